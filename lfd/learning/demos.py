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
import zipfile
import zlib
from pathlib import Path

import numpy as np

from lfd.learning.demo_checks import (
    LIMIT_TOLERANCE,
    check_demonstration,
    check_limit_tolerance,
    check_same_dt,
    check_set,
    names_from_array,
)
from lfd.learning.demoset import DemoFormatError, Demonstration, DemoSet
from lfd.learning.tasks import TaskSpec, check_names, check_point, check_whole
from lfd.robot.robots import RobotSpec

__all__ = ["REQUIRED_KEYS", "demo_files", "load_demos", "save_demonstration", "save_demos", "set_folder"]

REQUIRED_KEYS = ("q", "dt", "joint_names", "landmark_poses", "landmark_names", "robot")


def save_demonstration(path: str | Path, demo: Demonstration, joint_names, landmark_names,
                       robot: RobotSpec) -> Path:
    """Write one demonstration as an ``.npz`` of the documented format (its folder is made if
    missing). What ``load_demos`` would refuse in the file -- a shape, NaN, a sampling interval, a
    name -- is refused here, before anything is written (``DemoFormatError``)."""
    check_names(joint_names, "joint_names")
    check_names(landmark_names, "landmark_names")
    path = Path(path)
    path = path if path.suffix == ".npz" else path.with_suffix(path.suffix + ".npz")
    try:
        raw = {"q": np.asarray(demo.q, dtype=np.float64), "dt": np.asarray(demo.dt, dtype=np.float64),
               "joint_names": np.array(list(joint_names), dtype=str),
               "landmark_poses": np.asarray(demo.landmarks, dtype=np.float64),
               "landmark_names": np.array(list(landmark_names), dtype=str),
               "robot": np.array(json.dumps(robot.to_dict()))}
    except (TypeError, ValueError) as e:  # ragged rows, a dt that is not a number
        raise DemoFormatError.at(str(path), f"not an array of numbers: {e}") from e
    _check_one(path, raw)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, q=raw["q"], dt=raw["dt"], joint_names=raw["joint_names"], landmark_poses=raw["landmark_poses"],
             landmark_names=raw["landmark_names"], robot=raw["robot"])
    return path


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


def _read_npz(path: Path) -> dict:
    where = str(path)
    if not path.is_file():  # a folder, a FIFO (opening it would block), a broken link
        raise DemoFormatError.at(where, "not a regular file (a demonstration is an .npz file as numpy.savez writes)")
    if not zipfile.is_zipfile(path):
        raise DemoFormatError.at(where, "not a readable .npz file (not a zip archive as numpy.savez writes)")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in REQUIRED_KEYS if k not in z.files]
            if missing:
                raise DemoFormatError.at(where, f"missing key(s) {missing}; a demonstration needs "
                                                f"{list(REQUIRED_KEYS)}")
            raw = {k: z[k] for k in REQUIRED_KEYS}
    except DemoFormatError:
        raise
    except ValueError as e:
        if "pickle" in str(e):  # object arrays need pickle, which is refused
            raise DemoFormatError.at(where, f"cannot read without pickle ({e}); store names as plain string "
                                            "arrays") from e
        raise DemoFormatError.at(where, f"damaged .npz file: a member is not a readable array ({e})") from e
    except zlib.error as e:
        raise DemoFormatError.at(where, f"damaged .npz file: a compressed member does not decompress ({e})") from e
    except MemoryError as e:  # numpy allocates what a member's header claims before reading it
        raise DemoFormatError.at(where, f"damaged .npz file: a member's header claims an array too large to "
                                        f"hold ({e})") from e
    except (OSError, zipfile.BadZipFile, EOFError, KeyError, RuntimeError, NotImplementedError) as e:
        # RuntimeError: an encrypted member; NotImplementedError: a compression zipfile lacks
        raise DemoFormatError.at(where, f"not a readable .npz file ({type(e).__name__}: {e})") from e
    for k, v in raw.items():
        if not isinstance(v, np.ndarray):  # numpy returns a member that is not .npy as raw bytes
            raise DemoFormatError.at(where, f"key {k!r} is not a .npy array inside the archive (got "
                                            f"{type(v).__name__})")
    return raw


def _check_one(path: Path, raw: dict) -> tuple[Demonstration, tuple, tuple, RobotSpec]:
    where = str(path)
    try:
        robot = RobotSpec.from_dict(json.loads(str(raw["robot"])))
    except (ValueError, TypeError, RecursionError) as e:
        raise DemoFormatError.at(where, f"key 'robot' must be the JSON of a RobotSpec (name, urdf, end_link, "
                                        f"joint_names): {e}") from e
    joint_names = names_from_array(where, "joint_names", raw["joint_names"])
    landmark_names = names_from_array(where, "landmark_names", raw["landmark_names"])
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
    limit_tolerance = check_limit_tolerance(limit_tolerance)
    if time_steps is not None:
        check_whole(time_steps, "time_steps", 2)
    files, root = _demo_files(Path(path))
    task, ground_truth = _side_files(root)
    if time_steps is None:
        time_steps = task.time_steps if task is not None else 24
    demos, (_, joint_names, landmark_names, robot, _) = _read_consistent(files, time_steps)
    check_set(demos, [str(f) for f in files], joint_names, robot, task, str(root), str(files[0]),
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
                raise DemoFormatError.at(str(f), f"recorded on robot {robot.to_dict()} but {f0.name} on {r0.to_dict()}")
            if joint_names != j0:
                raise DemoFormatError.at(str(f), f"joint_names {list(joint_names)} differ from {f0.name}'s {list(j0)}")
            if landmark_names != l0:
                raise DemoFormatError.at(str(f), f"landmark_names {list(landmark_names)} (Z={len(landmark_names)}) "
                                                 f"differ from {f0.name}'s {list(l0)} (Z={len(l0)})")
            check_same_dt(str(f), demo.dt, f0.name, dt0)
        if demo.n_samples < time_steps:
            raise DemoFormatError.at(str(f), f"only {demo.n_samples} samples, fewer than the {time_steps} time "
                                             f"steps of the task model")
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
    if ds.task is not None and ds.task.reference_landmark not in ds.landmark_names:
        print(f"note: task.json's reference_landmark {ds.task.reference_landmark!r} is not among the landmarks: "
              "the set can be learned, but not the baseline that fixes the environment landmark to it "
              "(env='bowl', lfd-plan's manual variants)")
    return 0


if __name__ == "__main__":
    from lfd.cli import run_main
    from lfd.learning.demos import _main as main  # the package's module, whose error classes run_main knows

    run_main(main, prog="python -m lfd.learning.demos")
