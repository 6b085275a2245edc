"""The on-disk format of a demonstration set, and a loader that checks all of it.

Format
------
A demonstration set is a folder::

    DIR/
      <any name>.npz       one file per demonstration (the suffix in any case; hidden files skipped),
                           loaded in order of name
      task.json            the TaskSpec (lfd.learning.tasks) the set demonstrates; optional for
                           learning, needed to plan (its time step; plan.py refuses a model without)
      ground_truth.json    optional: the hidden truth of a synthetic set (evaluation only)

Each ``.npz`` (``numpy.savez``; no pickled objects) holds:

==================  ==============  ======================================================
key                 shape / type    meaning
==================  ==============  ======================================================
``q``               (S, d) float    joint configurations, radians, one row per sample
``dt``              () float        sampling interval, seconds (> 0, the same in every file)
``joint_names``     (d,) str        names of the columns of ``q``, as in the URDF
``landmark_poses``  (Z, 4, 4) float ``T_world_landmark`` of each sensed landmark (rigid, metres,
                                    within 20 m of the base), or
                    (S, Z, 4, 4)    one pose per sample when the landmarks were tracked during
                                    the demonstration (a hand that moves, a person)
``landmark_names``  (Z,) str        names, the same set and order in every file
``robot``           () str          JSON of ``lfd.robot.robots.RobotSpec.to_dict()``
==================  ==============  ======================================================

``world`` is the robot's base (URDF root) frame. See the README for converting a CSV
of joint angles into this format.
"""

from __future__ import annotations

import json
import math
import zipfile
import zlib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from lfd.errors import UserInputError
from lfd.learning.demo_checks import far_landmark, jumping_landmark, other_task_dt, same_interval, unusable_demos
from lfd.learning.tasks import MAX_DT, TaskSpec, check_names, check_point, check_stride, check_whole, is_real
from lfd.robot.robots import RobotSpec
from lfd.robot.se3 import not_rigid, rigid_errors

__all__ = [
    "REQUIRED_KEYS",
    "DemoFormatError",
    "DemoSet",
    "Demonstration",
    "check_demonstration",
    "check_demoset",
    "demo_files",
    "far_landmark",
    "jumping_landmark",
    "load_demos",
    "save_demonstration",
    "save_demos",
    "set_folder",
    "unusable_demos",
]

REQUIRED_KEYS = ("q", "dt", "joint_names", "landmark_poses", "landmark_names", "robot")
LIMIT_TOLERANCE = 0.02  # rad: recorded joints may sit this far outside the URDF limits


class DemoFormatError(UserInputError):
    """A demonstration set that cannot be used; the message says what, where, and what is expected."""


@dataclass(frozen=True)
class Demonstration:
    """One demonstration: ``q: (S, d)``, sampling interval ``dt``, landmarks ``(Z, 4, 4)`` (held
    still) or ``(S, Z, 4, 4)`` (tracked: the pose of each landmark at each sample)."""

    q: np.ndarray
    dt: float
    landmarks: np.ndarray
    name: str = ""

    def __post_init__(self):  # a list of rows had no .shape: n_samples raised AttributeError
        object.__setattr__(self, "q", np.asarray(self.q))
        object.__setattr__(self, "landmarks", np.asarray(self.landmarks))

    @property
    def n_samples(self) -> int:
        return int(self.q.shape[0])

    @property
    def duration(self) -> float:
        return (self.n_samples - 1) * self.dt


@dataclass(frozen=True)
class DemoSet:
    """Demonstrations that share a robot, joints, landmarks and sampling interval."""

    demos: tuple[Demonstration, ...]
    joint_names: tuple[str, ...]
    landmark_names: tuple[str, ...]
    robot: RobotSpec
    task: TaskSpec | None = None
    ground_truth: dict | None = None
    root: Path | None = None

    @property
    def dt(self) -> float:
        return self.demos[0].dt

    @property
    def n_observations(self) -> int:
        return sum(d.n_samples for d in self.demos)

    def subsample(self, stride: int) -> DemoSet:
        """Every ``stride``-th sample of each demonstration, the first included, at ``stride * dt``
        (up to ``stride - 1`` samples after the last kept one are dropped).

        The paper's remedy for densely sampled demonstrations (Sec. VI-B: the 50 Hz pour "could have
        been mitigated simply by subsampling during learning"). The task's ``dt`` is scaled with the
        samples, so a model learned from the result plans and executes at the new interval.
        The task's ``subsample`` (its default stride) becomes 1. ``stride == 1`` returns this set
        unchanged.
        """
        stride = check_stride(stride, "subsample stride")
        if stride == 1:
            return self
        demos = tuple(replace(d, q=d.q[::stride], dt=d.dt * stride,
                              landmarks=d.landmarks[::stride] if np.ndim(d.landmarks) == 4 else d.landmarks)
                      for d in self.demos)
        # the task's own learning stride is spent: the thinned set is learned from every sample
        task = replace(self.task, dt=self.task.dt * stride, subsample=1) if self.task is not None else None
        return replace(self, demos=demos, task=task)

    def landmark_index(self, name: str) -> int:
        if name not in self.landmark_names:
            raise ValueError(f"landmark {name!r} is not among {list(self.landmark_names)}")
        return self.landmark_names.index(name)


def save_demonstration(path: str | Path, demo: Demonstration, joint_names, landmark_names,
                       robot: RobotSpec) -> Path:
    """Write one demonstration as an ``.npz`` of the documented format."""
    check_names(joint_names, "joint_names")
    check_names(landmark_names, "landmark_names")
    path = Path(path)
    np.savez(path, q=np.asarray(demo.q, dtype=np.float64), dt=np.float64(demo.dt),
             joint_names=np.array(list(joint_names), dtype=str),
             landmark_poses=np.asarray(demo.landmarks, dtype=np.float64),
             landmark_names=np.array(list(landmark_names), dtype=str),
             robot=np.array(json.dumps(robot.to_dict())))
    return path if path.suffix == ".npz" else path.with_suffix(path.suffix + ".npz")


def save_demos(out_dir: str | Path, demoset: DemoSet) -> list[Path]:
    """Write a whole set (``demo_000.npz`` …, ``task.json``, ``ground_truth.json``)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [save_demonstration(out_dir / f"demo_{i:03d}.npz", d, demoset.joint_names,
                                demoset.landmark_names, demoset.robot)
             for i, d in enumerate(demoset.demos)]
    if demoset.task is not None:
        demoset.task.save(out_dir / "task.json")
    if demoset.ground_truth is not None:
        (out_dir / "ground_truth.json").write_text(json.dumps(demoset.ground_truth, indent=2) + "\n")
    return paths


def _fail(where: str, what: str) -> DemoFormatError:
    return DemoFormatError(f"{where}: {what}")


def _read_npz(path: Path) -> dict:
    where = str(path)
    if not path.is_file():  # a folder, a FIFO (opening it would block), a broken link
        raise _fail(where, "not a regular file (a demonstration is an .npz file as numpy.savez writes)")
    if not zipfile.is_zipfile(path):
        raise _fail(where, "not a readable .npz file (not a zip archive as numpy.savez writes)")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in REQUIRED_KEYS if k not in z.files]
            if missing:
                raise _fail(where, f"missing key(s) {missing}; a demonstration needs {list(REQUIRED_KEYS)}")
            raw = {k: z[k] for k in REQUIRED_KEYS}
    except DemoFormatError:
        raise
    except ValueError as e:
        if "pickle" in str(e):  # object arrays need pickle, which is refused
            raise _fail(where, f"cannot read without pickle ({e}); store names as plain string arrays") from e
        raise _fail(where, f"damaged .npz file: a member is not a readable array ({e})") from e
    except zlib.error as e:
        raise _fail(where, f"damaged .npz file: a compressed member does not decompress ({e})") from e
    except MemoryError as e:  # numpy allocates what a member's header claims before reading it
        raise _fail(where, f"damaged .npz file: a member's header claims an array too large to hold ({e})") from e
    except (OSError, zipfile.BadZipFile, EOFError, KeyError, RuntimeError, NotImplementedError) as e:
        # RuntimeError: an encrypted member; NotImplementedError: a compression zipfile lacks
        raise _fail(where, f"not a readable .npz file ({type(e).__name__}: {e})") from e
    for k, v in raw.items():
        if not isinstance(v, np.ndarray):  # numpy returns a member that is not .npy as raw bytes
            raise _fail(where, f"key {k!r} is not a .npy array inside the archive (got {type(v).__name__})")
    return raw


def _as_float(where: str, key: str, value, ndim: int) -> np.ndarray:
    if value.dtype.kind not in "fiu":
        raise _fail(where, f"key {key!r} must be numeric, got dtype {value.dtype}")
    value = value.astype(np.float64)
    if value.ndim != ndim:
        raise _fail(where, f"key {key!r} must have {ndim} dimension(s), got shape {value.shape}")
    if not np.all(np.isfinite(value)):
        bad = np.argwhere(~np.isfinite(value))[0].tolist()
        raise _fail(where, f"key {key!r} holds NaN or infinite values (first at index {bad})")
    return value


def _as_names(where: str, key: str, value) -> tuple[str, ...]:
    if value.dtype.kind not in "US" or value.ndim != 1:
        raise _fail(where, f"key {key!r} must be a 1-D array of strings, got dtype {value.dtype} "
                           f"and shape {value.shape}")
    try:  # bytes (dtype S, e.g. written by Python 2 or h5py) are decoded, not shown as "b'...'"
        names = tuple(v.decode("utf-8") if isinstance(v, bytes) else str(v) for v in value.tolist())
    except UnicodeDecodeError as e:
        raise _fail(where, f"key {key!r} holds bytes that are not UTF-8 text ({e})") from e
    if len(set(names)) != len(names):
        raise _fail(where, f"key {key!r} repeats a name: {list(names)}")
    if not all(n.strip() for n in names):  # '  ' was a name no option could give
        raise _fail(where, f"key {key!r} holds an empty name: {list(names)}")
    return names


def _landmark_poses(where: str, value, names: tuple, n_samples: int, dt: float) -> np.ndarray:
    """``landmark_poses`` checked: ``(Z, 4, 4)`` or ``(S, Z, 4, 4)`` (tracked, one pose per sample
    every ``dt`` s), finite and rigid, ``Z`` the names' count, metres in the base frame, tracked
    ones moving as an object can (``lfd.learning.demo_checks``)."""
    shape = f"({len(names)}, 4, 4) or, tracked, ({n_samples}, {len(names)}, 4, 4)"
    if value.dtype.kind not in "fiu" or value.ndim not in (3, 4):
        raise _fail(where, f"key 'landmark_poses' must be numeric of shape {shape} to match 'landmark_names' "
                           f"and 'q', got dtype {value.dtype} and shape {value.shape}")
    poses = _as_float(where, "landmark_poses", value, value.ndim)
    if poses.shape[-3:] != (len(names), 4, 4) or (poses.ndim == 4 and poses.shape[0] != n_samples):
        raise _fail(where, f"key 'landmark_poses' must have shape {shape} to match 'landmark_names' and 'q', "
                           f"got {poses.shape}")
    if poses.shape[-3] == 0:
        raise _fail(where, "no sensed landmarks: 'landmark_poses' is empty")
    bad = np.argwhere(not_rigid(poses))
    if bad.size:
        idx = tuple(int(x) for x in bad[0])
        ortho, det, bottom = rigid_errors(poses[idx])
        at = f" at sample {idx[0]}" if poses.ndim == 4 else ""
        raise _fail(where, f"landmark {names[idx[-1]]!r} pose{at} is not a rigid transform "
                           f"(|R^T R - I| = {ortho:.2g}, |det R - 1| = {det:.2g}, "
                           f"bottom row error {bottom:.2g})")
    why = far_landmark(poses, names) or jumping_landmark(poses, names, dt)
    if why:
        raise _fail(where, why)
    return poses


def check_demonstration(where: str, demo: Demonstration, joint_names, landmark_names) -> Demonstration:
    """``demo`` checked on its own against its set's names (``where`` starts each message): ``q``
    finite ``(S, d)``, one column per joint name; ``dt`` in ``(0, MAX_DT]``; its landmark poses
    as ``_landmark_poses`` checks them. Returned with float64 arrays. The checks of a file's
    arrays (``load_demos``) and of a ``DemoSet`` built in Python (``check_demoset``)."""
    q = _as_float(where, "q", np.asarray(demo.q), 2)
    if q.shape[1] != len(joint_names):
        raise _fail(where, f"key 'q' has {q.shape[1]} columns but 'joint_names' names {len(joint_names)} "
                           f"joints")
    dt = _as_float(where, "dt", np.asarray(demo.dt), 0)
    if not 0 < dt <= MAX_DT:
        hint = " (milliseconds given as seconds?)" if dt > MAX_DT else ""
        raise _fail(where, f"key 'dt' (sampling interval, seconds) must be positive and at most {MAX_DT:g}, "
                           f"got {float(dt)}{hint}")
    poses = _landmark_poses(where, np.asarray(demo.landmarks), tuple(landmark_names), len(q), float(dt))
    return Demonstration(q=q, dt=float(dt), landmarks=poses, name=demo.name)


def _check_one(path: Path, raw: dict) -> tuple[Demonstration, tuple, tuple, RobotSpec]:
    where = str(path)
    try:
        robot = RobotSpec.from_dict(json.loads(str(raw["robot"])))
    except (ValueError, TypeError) as e:
        raise _fail(where, f"key 'robot' must be the JSON of a RobotSpec (name, urdf, end_link, "
                           f"joint_names): {e}") from e
    joint_names = _as_names(where, "joint_names", raw["joint_names"])
    landmark_names = _as_names(where, "landmark_names", raw["landmark_names"])
    demo = check_demonstration(where, Demonstration(q=raw["q"], dt=raw["dt"], landmarks=raw["landmark_poses"],
                                                    name=path.stem), joint_names, landmark_names)
    return demo, joint_names, landmark_names, robot


def _read_ground_truth(path: Path) -> dict:
    """``ground_truth.json``: a JSON object; ``tool_point`` (3 finite numbers), ``bowl_landmark``
    (a name) and ``reference_points`` (an object of named gripper-frame points, e.g. where the
    demonstrator aimed; ``lfd-train`` reports the learned tool point's distance to each), when
    present, are checked here, before any fit reads them."""
    try:
        gt = json.loads(path.read_text())
    except (ValueError, RecursionError) as e:
        raise DemoFormatError(f"{path}: not valid JSON: {e}") from e
    if not isinstance(gt, dict):
        raise DemoFormatError(f"{path}: must be a JSON object, got {type(gt).__name__}")
    if "tool_point" in gt:
        try:
            check_point(gt["tool_point"], "'tool_point'")
        except ValueError as e:
            raise DemoFormatError(f"{path}: {e}") from e
    refs = gt.get("reference_points", {})
    if not isinstance(refs, dict):
        raise DemoFormatError(f"{path}: 'reference_points' must be an object of named points, got {type(refs).__name__}")
    for name, point in refs.items():
        try:
            check_point(point, f"reference point {name!r}")
        except ValueError as e:
            raise DemoFormatError(f"{path}: {e}") from e
    if "bowl_landmark" in gt and not isinstance(gt["bowl_landmark"], str):
        raise DemoFormatError(f"{path}: 'bowl_landmark' must be a landmark's name, got {gt['bowl_landmark']!r}")
    return gt


def _check_limits(where: str, q: np.ndarray, joint_names, lower, upper, tol: float) -> None:
    below = q < lower - tol
    above = q > upper + tol
    if below.any() or above.any():
        s, j = np.argwhere(below | above)[0]
        raise _fail(where, f"sample {s}, joint {joint_names[j]!r} = {q[s, j]:.4f} rad is outside its "
                           f"limits [{lower[j]:.4f}, {upper[j]:.4f}] (tolerance {tol} rad)")


def _same_dt(where: str, dt: float, first: str, dt0: float) -> None:
    if not same_interval(dt, dt0):
        raise _fail(where, f"sampling interval dt={dt} differs from {first}'s dt={dt0}")


def _check_tolerance(limit_tolerance) -> float:
    """``limit_tolerance`` as a float if it is a finite angle >= 0 (NaN turned the limit check off)."""
    if not (is_real(limit_tolerance) and math.isfinite(limit_tolerance) and limit_tolerance >= 0):
        raise ValueError(f"limit_tolerance must be a finite angle >= 0 (rad), got {limit_tolerance!r}")
    return float(limit_tolerance)


def _check_set(demos, wheres: list[str], joint_names: tuple, robot: RobotSpec, task: TaskSpec | None,
               set_where: str, names_where: str, task_where: str, kin, limit_tolerance: float):
    """What a set's demonstrations, each checked on its own and with one ``dt``, must satisfy
    together with their robot and task: the task's ``dt`` is theirs, the joint names are the
    robot's in its order, ``kin`` (built from ``robot`` when None) is the robot's, every sample
    is within its joint limits (``limit_tolerance`` rad), and they can be learned from
    (``unusable_demos``). Returns ``kin``. ``load_demos`` and ``check_demoset``; ``wheres`` name
    the demonstrations in messages, ``set_where`` the set, ``names_where`` its joint names and
    ``task_where`` its task."""
    why = other_task_dt(task.dt, demos[0].dt) if task is not None else None
    if why:
        raise DemoFormatError(f"{task_where}: {why}")
    unknown = [n for n in joint_names if n not in robot.joint_names]
    if unknown:
        raise _fail(names_where, f"unknown joint name(s) {unknown}; robot {robot.name!r} has "
                               f"{list(robot.joint_names)}")
    if joint_names != robot.joint_names:
        raise _fail(names_where, f"joint_names must be {list(robot.joint_names)} in this order, got "
                               f"{list(joint_names)}")
    if kin is None:
        from lfd.robot.kinematics import KinematicModel, KinematicsError
        try:
            kin = KinematicModel.from_spec(robot)
        except KinematicsError as e:
            raise DemoFormatError(f"{names_where}: robot {robot.name!r} cannot be loaded: {e}") from e
    elif tuple(kin.joint_names) != robot.joint_names or kin.end_link != robot.end_link:
        raise DemoFormatError(f"{set_where}: the kinematic model (kin) is of joints {list(kin.joint_names)} to "
                              f"{kin.end_link!r}, not of the demonstrations' robot {robot.name!r} (joints "
                              f"{list(robot.joint_names)} to {robot.end_link!r})")
    lower, upper = kin.lower.cpu().numpy(), kin.upper.cpu().numpy()
    for where, d in zip(wheres, demos):
        _check_limits(where, d.q, joint_names, lower, upper, limit_tolerance)
    why = unusable_demos([d.q for d in demos], [d.name for d in demos])
    if why:
        raise DemoFormatError(f"{set_where}: {why}")
    return kin


def check_demoset(demoset: DemoSet, kin=None, limit_tolerance: float = LIMIT_TOLERANCE) -> tuple[DemoSet, object]:
    """A ``DemoSet`` however it was made (built in Python, ``lfd.io.recordings``) checked as
    ``load_demos`` checks a set's files: each demonstration (``check_demonstration``), one ``dt``,
    the task, the robot and ``kin`` (``_check_set``). Returns the set with float64 arrays and
    ``kin`` (built from ``demoset.robot`` when None); ``DemoFormatError`` naming the
    demonstration otherwise. ``lfd.learning.learn.fit`` calls it on what it is given."""
    limit_tolerance = _check_tolerance(limit_tolerance)
    if not isinstance(demoset, DemoSet):
        raise TypeError(f"expected a DemoSet (lfd.learning.demos), got {type(demoset).__name__}")
    if not isinstance(demoset.robot, RobotSpec):
        raise DemoFormatError(f"the DemoSet: robot must be a RobotSpec, got {type(demoset.robot).__name__}")
    if isinstance(demoset.demos, (str, bytes)) or not len(demoset.demos):
        raise DemoFormatError("the DemoSet: no demonstrations")
    joint_names = _as_names("the DemoSet", "joint_names", np.asarray(demoset.joint_names))
    landmark_names = _as_names("the DemoSet", "landmark_names", np.asarray(demoset.landmark_names))
    wheres = [f"demonstration {d.name!r}" if getattr(d, "name", "") else f"demonstration {i}"
              for i, d in enumerate(demoset.demos)]
    demos: list[Demonstration] = []
    for where, d in zip(wheres, demoset.demos):
        demo = check_demonstration(where, d, joint_names, landmark_names)
        if demos:
            _same_dt(where, demo.dt, demos[0].name or "demonstration 0", demos[0].dt)
        demos.append(demo)
    kin = _check_set(demos, wheres, joint_names, demoset.robot, demoset.task, "the DemoSet", "the DemoSet",
                     "the DemoSet's task", kin, limit_tolerance)
    return replace(demoset, demos=tuple(demos), joint_names=joint_names, landmark_names=landmark_names), kin


def load_demos(path: str | Path, time_steps: int | None = None, kin=None,
               limit_tolerance: float = LIMIT_TOLERANCE) -> DemoSet:
    """Load and validate a demonstration set.

    Parameters
    ----------
    path : the folder (or a single ``.npz`` file).
    time_steps : every demonstration must have at least this many samples; defaults to
        ``task.json``'s ``time_steps`` (or 24 without one).
    kin : a ``KinematicModel`` for the joint limits; built from the files' robot when None.
    limit_tolerance : how far (rad) a sample may lie outside the URDF limits.

    Raises
    ------
    DemoFormatError
        naming the file, the demonstration and the key for each problem.
    """
    limit_tolerance = _check_tolerance(limit_tolerance)
    if time_steps is not None:
        check_whole(time_steps, "time_steps", 2)
    files, root = _demo_files(Path(path))
    task, ground_truth = _side_files(root)
    if time_steps is None:
        time_steps = task.time_steps if task is not None else 24
    demos, (_, joint_names, landmark_names, robot, _) = _read_consistent(files, time_steps)
    _check_set(demos, [str(f) for f in files], joint_names, robot, task, str(root), str(files[0]),
               str(root / "task.json"), kin, limit_tolerance)
    return DemoSet(demos=tuple(demos), joint_names=joint_names, landmark_names=landmark_names,
                   robot=robot, task=task, ground_truth=ground_truth, root=root)


def demo_files(folder: str | Path) -> list[Path]:
    """The demonstration files of a set's folder: its ``.npz`` files, the suffix in any case,
    hidden ones (``._demo_000.npz``, macOS's copies on shared drives) skipped, sorted by name
    without regard to case (then with it); ``[]`` when ``folder`` is not a folder."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    found = (p for p in folder.iterdir() if p.suffix.lower() == ".npz" and not p.name.startswith("."))
    return sorted(found, key=lambda p: (p.name.lower(), p.name))


def set_folder(path: str | Path) -> Path:
    """The folder of a set given as ``path`` (a folder, or one ``.npz`` of it): where its
    ``task.json`` and ``ground_truth.json`` are read."""
    path = Path(path)
    return path.parent if path.is_file() else path


def _demo_files(path: Path) -> tuple[list[Path], Path]:
    """The ``.npz`` files of a set (a folder, or one file) and the folder holding them."""
    if not path.exists():
        raise DemoFormatError(f"{path}: no such demonstration folder or file")
    if not (path.is_dir() or path.is_file()):
        raise DemoFormatError(f"{path}: neither a folder of demonstrations nor an .npz file (a device, a "
                              f"socket or a pipe?)")
    root = set_folder(path)
    files = [path] if path.is_file() else demo_files(path)
    if not files:
        raise DemoFormatError(f"{path}: no demonstration files (*.npz) in this folder")
    return files, root


def _side_files(root: Path):
    """``(task, ground_truth)``: ``task.json`` as a ``TaskSpec`` and ``ground_truth.json``, each
    None when absent."""
    for name in ("task.json", "ground_truth.json"):
        side = root / name
        if (side.exists() or side.is_symlink()) and not side.is_file():  # was taken for absent
            raise DemoFormatError(f"{side}: not a readable file (a folder or a broken link)")
    task = None
    if (root / "task.json").is_file():
        try:
            task = TaskSpec.load(root / "task.json")
        except (ValueError, KeyError, TypeError, RecursionError) as e:
            raise DemoFormatError(f"{root / 'task.json'}: not a valid task definition: {e}") from e
    ground_truth = _read_ground_truth(root / "ground_truth.json") if (root / "ground_truth.json").is_file() else None
    return task, ground_truth


def _read_consistent(files: list[Path], time_steps: int):
    """Every file checked on its own and against the first (robot, joint and landmark names,
    dt), each with at least ``time_steps`` samples: ``(demos, (first file, joint_names,
    landmark_names, robot, dt))``."""
    demos, first = [], None
    for f in files:
        demo, joint_names, landmark_names, robot = _check_one(f, _read_npz(f))
        if first is None:
            first = (f, joint_names, landmark_names, robot, demo.dt)
        else:
            f0, j0, l0, r0, dt0 = first
            if robot != r0:
                raise _fail(str(f), f"recorded on robot {robot.to_dict()} but {f0.name} on {r0.to_dict()}")
            if joint_names != j0:
                raise _fail(str(f), f"joint_names {list(joint_names)} differ from {f0.name}'s {list(j0)}")
            if landmark_names != l0:
                raise _fail(str(f), f"landmark_names {list(landmark_names)} (Z={len(landmark_names)}) differ "
                                    f"from {f0.name}'s {list(l0)} (Z={len(l0)})")
            _same_dt(str(f), demo.dt, f0.name, dt0)
        if demo.n_samples < time_steps:
            raise _fail(str(f), f"only {demo.n_samples} samples, fewer than the {time_steps} time steps of "
                                f"the task model")
        demos.append(demo)
    assert first is not None  # files is not empty (_demo_files)
    return demos, first


def _main(argv=None) -> int:
    """``python -m lfd.learning.demos DIR``: validate a demonstration set and summarise it."""
    from lfd.cli import ArgumentParser

    parser = ArgumentParser(prog="python -m lfd.learning.demos", description=_main.__doc__)
    parser.add_argument("path", help="folder of .npz demonstrations (or one .npz file)")
    parser.add_argument("--time-steps", type=int, default=None,
                        help="minimum samples per demonstration (default: task.json's, or 24)")
    args = parser.parse_args(argv)
    if args.time_steps is not None and args.time_steps < 2:
        from lfd.cli import UsageError
        raise UsageError(f"--time-steps must be at least 2, got {args.time_steps}")
    ds = load_demos(args.path, time_steps=args.time_steps)
    lengths = [d.n_samples for d in ds.demos]
    print(f"{len(ds.demos)} demonstrations of {ds.task.name if ds.task else 'an unnamed task'} on "
          f"{ds.robot.name}: {ds.n_observations} observations (per demonstration {min(lengths)}-"
          f"{max(lengths)}), dt={ds.dt:g} s, landmarks {list(ds.landmark_names)}")
    return 0


if __name__ == "__main__":
    from lfd.cli import run_main
    from lfd.learning.demos import _main as main  # the package's module, whose error classes run_main knows

    run_main(main, prog="python -m lfd.learning.demos")
