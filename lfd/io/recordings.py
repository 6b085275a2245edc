"""Recorded demonstrations from CSV files: joint recordings and tracked landmarks, resampled.

A recording of one demonstration is a joint CSV and, optionally, a landmark CSV, either in a
folder of their own (``DEMO/joints.csv``, ``DEMO/landmarks.csv``) or as a pair of files
(``DEMO_joints.csv``, ``DEMO_landmarks.csv``), taken in order of name. File names match in any
case and hidden entries are skipped (``find_recordings``). The files are UTF-8 text (a
spreadsheet's byte-order mark is allowed).

* **Joints**: a header row, a time column (seconds) and one column per joint of the robot, named
  as in its URDF: the Baxter SDK's joint recorder writes ``time,left_s0,left_s1,...`` (its other
  columns, the gripper and the other arm, are ignored). Another layout is described by a
  ``JointColumns`` mapping (the time column's name, each joint's column, degrees or radians).
  Angles are unwrapped (a recorder that wraps at ±pi does not make a joint jump by 2 pi) and
  moved by whole turns into the joint's limits (one that reports angles in [0, 2 pi)).
* **Landmarks**: a header row and the columns ``time,name,x,y,z,qx,qy,qz,qw``: the pose of the
  landmark ``name`` at ``time`` in a frame the user names (``T_base_frame``, the robot base by
  default), metres and a unit quaternion. A landmark read once holds still; one read at several
  times is tracked and interpolated at the joint samples' times (positions linearly,
  orientations by slerp), so a tracker running at another rate is aligned by time.

Every demonstration is resampled to one rate (joints linearly) from its first joint sample.
What a recording must satisfy, each refused with one line naming the file and row
(``RecordingError``): the columns exist, every value is a number, time increases (joint rows;
each landmark's rows), no gap between samples is longer than ``max_gap``, quaternions are unit
(within ``QUAT_TOLERANCE``), every demonstration names the same landmarks, every landmark
has a reading within ``max_gap`` of both ends of each demonstration, and none is farther than
``lfd.learning.demo_checks.MAX_LANDMARK_DISTANCE`` (20 m) from the robot's base (another unit). Pauses at the start and
end (every joint within ``trim`` rad of where it starts or ends) can be trimmed, and are reported.
``import_recordings`` returns the ``DemoSet`` and a report; ``lfd.io.import_csv`` writes it.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from lfd.errors import UserInputError
from lfd.learning.demo_checks import LIMIT_TOLERANCE, far_landmark, jumping_landmark, other_task_dt, unusable_demos
from lfd.learning.demoset import Demonstration, DemoSet
from lfd.learning.tasks import TaskSpec, is_real
from lfd.robot.robots import RobotSpec
from lfd.robot.se3 import not_rigid

__all__ = ["LANDMARK_COLUMNS", "MAX_DEMO_S", "QUAT_TOLERANCE", "JointColumns", "RecordingError", "find_recordings",
           "import_recordings"]

LANDMARK_COLUMNS = ("time", "name", "x", "y", "z", "qx", "qy", "qz", "qw")
QUAT_TOLERANCE = 1e-3  # |norm - 1| allowed in a recorded quaternion
MAX_DEMO_S = 3600.0  # s: a demonstration longer than an hour is a time stamp in error (a task takes seconds)


class RecordingError(UserInputError):
    """A recording that cannot be imported (the message names the file, the row and the reason)."""


@dataclass(frozen=True)
class JointColumns:
    """How a joint CSV names its columns: ``time`` the time column (seconds); ``joints`` the
    column of each of the robot's joints (None: the joints' own URDF names, as the Baxter
    recorder writes them); ``degrees``: angles in degrees instead of radians."""

    time: str = "time"
    joints: dict = field(default_factory=dict)
    degrees: bool = False

    def __post_init__(self):  # degrees="false" (a string) was read as True
        if not isinstance(self.degrees, (bool, np.bool_)):
            raise RecordingError(f"JointColumns: 'degrees' must be true or false, got {self.degrees!r}")
        object.__setattr__(self, "degrees", bool(self.degrees))

    @classmethod
    def load(cls, path: str | Path) -> JointColumns:
        """A mapping file: ``{"time": "t", "joints": {"left_s0": "j0", ...}, "degrees": false}``."""
        try:
            d = json.loads(Path(path).read_text())
            if not isinstance(d, dict) or not set(d) <= {"time", "joints", "degrees"}:
                raise ValueError("expected an object with the keys time, joints, degrees")
            names = [d.get("time", "time"), *dict(d.get("joints", {})).values()]
            if not all(isinstance(c, str) and c for c in names):  # None was looked up as column 'None'
                raise ValueError(f"column names must be non-empty strings, got {names!r}")
            return cls(time=str(d.get("time", "time")), joints={str(k): str(v) for k, v in d.get("joints", {}).items()},
                       degrees=d.get("degrees", False))
        except (OSError, ValueError, TypeError, AttributeError, RecursionError) as e:
            raise RecordingError(f"{path}: not a joint-column mapping ({e})") from e

    def column(self, joint: str) -> str:
        return self.joints.get(joint, joint)

    def check(self, robot: RobotSpec) -> None:
        """``RecordingError`` when the mapping names a joint ``robot`` does not have (a misspelt
        key: the default column was read instead) or reads one column for two joints or the time."""
        unknown = sorted(set(self.joints) - set(robot.joint_names))
        if unknown:
            raise RecordingError(f"the joint-column mapping names joint(s) {unknown}, which robot {robot.name!r} "
                                 f"does not have (its joints: {list(robot.joint_names)})")
        cols = [self.time, *(self.column(j) for j in robot.joint_names)]
        repeated = sorted({c for c in cols if cols.count(c) > 1})
        if repeated:
            raise RecordingError(f"the joint-column mapping reads column(s) {repeated} for more than one joint "
                                 f"(or for the time)")


def find_recordings(root: str | Path) -> list[tuple[str, Path, Path | None]]:
    """``(name, joint CSV, landmark CSV or None)`` of every demonstration under ``root``, in order
    of name.

    File names are matched without regard to case (``joints.CSV`` as written on some systems);
    hidden entries (``.name``, such as the ``._*`` files macOS leaves on shared drives) are skipped.
    Two entries whose names differ only in case, or two recordings of one name (``DEMO/`` and
    ``DEMO_joints.csv``), are refused: one would stand for the other on another file system.
    """
    root = Path(root)
    if not root.is_dir():
        raise RecordingError(f"{root}: " + ("a file, not a folder of recordings" if root.exists()
                                            else "no such folder of recordings"))

    def visible(folder: Path) -> dict[str, Path]:  # lower-case name -> entry
        out: dict[str, Path] = {}
        for p in sorted(folder.iterdir()):
            if p.name.startswith("."):
                continue
            if p.name.lower() in out:
                raise RecordingError(f"{out[p.name.lower()]} and {p}: names that differ only in case; "
                                     f"keep one of them")
            out[p.name.lower()] = p
        return out

    top = visible(root)
    found = []
    for d in (p for p in top.values() if p.is_dir()):
        inside = visible(d)
        if "joints.csv" in inside and inside["joints.csv"].is_file():
            lm = inside.get("landmarks.csv")
            found.append((d.name, inside["joints.csv"], lm if lm is not None and lm.is_file() else None))
    for low, f in top.items():
        if low.endswith("_joints.csv") and f.is_file():
            name = f.name[: -len("_joints.csv")]
            lm = top.get(f"{name.lower()}_landmarks.csv")
            found.append((name, f, lm if lm is not None and lm.is_file() else None))
    found.sort(key=lambda r: (r[0].lower(), r[0]))
    for (n1, j1, _), (n2, j2, _) in itertools.pairwise(found):
        if n1.lower() == n2.lower():
            raise RecordingError(f"{j1} and {j2}: two recordings named {n1!r}; keep one of them")
    if not found:
        raise RecordingError(f"{root}: no recordings (DEMO/joints.csv or DEMO_joints.csv)")
    return found


def _read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    try:
        # utf-8-sig: a spreadsheet's byte-order mark is not part of the first column's name
        with path.open(newline="", encoding="utf-8-sig") as fh:
            rows = [r for r in csv.reader(fh) if r and any(c.strip() for c in r)]
    except UnicodeDecodeError as e:
        raise RecordingError(f"{path}: not UTF-8 text ({e}); save it as 'CSV UTF-8'") from e
    except (OSError, csv.Error) as e:
        raise RecordingError(f"{path}: cannot be read as CSV ({e})") from e
    if len(rows) < 2:
        raise RecordingError(f"{path}: needs a header row and at least one data row")
    other = next((sep for sep in ";\t|" if len(rows[0]) == 1 and sep in rows[0][0]), None)
    if other is not None:  # a spreadsheet in a locale whose decimal mark is ','
        raise RecordingError(f"{path}: the header {rows[0][0]!r} is one column: the fields are separated by "
                             f"{other!r}, not ','; save it as comma-separated CSV, with '.' as the decimal mark")
    return [c.strip() for c in rows[0]], rows[1:]


def _numbers(path: Path, header: list[str], rows: list[list[str]], columns) -> np.ndarray:
    """``(rows, len(columns))`` floats of the named columns; a missing column or a value that is
    not a finite number is refused with its row (1-based, the header is row 1)."""
    missing = [c for c in columns if c not in header]
    if missing:
        raise RecordingError(f"{path}: missing column(s) {missing} (header: {header})")
    twice = sorted({c for c in columns if header.count(c) > 1})
    if twice:  # the first copy was read without a word
        raise RecordingError(f"{path}: the header repeats column(s) {twice}")
    idx = [header.index(c) for c in columns]
    out = np.empty((len(rows), len(idx)))
    for i, r in enumerate(rows):
        for j, k in enumerate(idx):
            try:
                out[i, j] = float(r[k])
            except (ValueError, IndexError):
                out[i, j] = math.nan
            if not math.isfinite(out[i, j]):
                raise RecordingError(f"{path}: row {i + 2}, column {columns[j]!r}: "
                                     f"{r[k] if k < len(r) else '(missing)'!r} is not a finite number")
    return out


def _check_times(path: Path, t: np.ndarray, max_gap: float, what: str = "", rows=None) -> None:
    """Time increases and has no gap over ``max_gap``; ``rows``: the file's data-row index of
    each entry of ``t`` (default: consecutive), for the message."""
    d = np.diff(t)
    if (d <= 0).any():
        i = int(np.flatnonzero(d <= 0)[0])
        row = (i + 1 if rows is None else int(rows[i + 1])) + 2  # 1-based, after the header
        raise RecordingError(f"{path}: {what}time does not increase at row {row} ({t[i + 1]:g} s after {t[i]:g} s)")
    if (d > max_gap).any():
        i = int(np.argmax(d))
        raise RecordingError(f"{path}: {what}a gap of {d[i]:.3g} s between {t[i]:g} s and {t[i + 1]:g} s "
                             f"(longer than --max-gap {max_gap:g} s)")


def _joints(path: Path, robot: RobotSpec, cols: JointColumns, max_gap: float) -> tuple[np.ndarray, np.ndarray]:
    """Times ``(S,)`` and unwrapped joint angles ``(S, d)`` in radians."""
    header, rows = _read_csv(path)
    names = [cols.time] + [cols.column(j) for j in robot.joint_names]
    a = _numbers(path, header, rows, names)
    t, q = a[:, 0], a[:, 1:]
    _check_times(path, t, max_gap)
    if cols.degrees:
        q = np.deg2rad(q)
    return t, np.unwrap(q, axis=0)


def _landmark_tracks(path: Path, T_base_frame: np.ndarray, max_gap: float) -> dict:
    """``{name: (times (K,), T_base_landmark (K, 4, 4))}`` from a landmark CSV."""
    header, rows = _read_csv(path)
    if "name" not in header:
        raise RecordingError(f"{path}: missing column(s) ['name'] (header: {header})")
    k = header.index("name")
    a = _numbers(path, header, rows, [c for c in LANDMARK_COLUMNS if c != "name"])
    names = np.array([r[k].strip() if k < len(r) else "" for r in rows])
    if (names == "").any():
        raise RecordingError(f"{path}: row {int(np.flatnonzero(names == '')[0]) + 2}: empty landmark name")
    norm = np.linalg.norm(a[:, 4:8], axis=1)
    if (np.abs(norm - 1) > QUAT_TOLERANCE).any():
        i = int(np.argmax(np.abs(norm - 1)))
        raise RecordingError(f"{path}: row {i + 2}: quaternion (qx, qy, qz, qw) has norm {norm[i]:.4g}, "
                             f"not 1 (within {QUAT_TOLERANCE:g})")
    tracks = {}
    for name in dict.fromkeys(names.tolist()):  # in order of first appearance
        sel = np.flatnonzero(names == name)
        t = a[sel, 0]
        _check_times(path, t, max_gap, what=f"landmark {name!r}: ", rows=sel)
        T = np.tile(np.eye(4), (len(sel), 1, 1))
        T[:, :3, :3] = Rotation.from_quat(a[sel, 4:8] / norm[sel, None]).as_matrix()
        T[:, :3, 3] = a[sel, 1:4]
        tracks[name] = (t, T_base_frame @ T)
        # at the readings' own times: resampled, a one-reading glitch is averaged under the limit
        # (a landmark in the wrong unit is named first: it also "jumps")
        raw = tracks[name][1][:, None]  # (K, 1, 4, 4)
        why = far_landmark(raw, [name]) or (jumping_landmark(raw, [name], np.diff(t)) if len(t) > 1 else None)
        if why:
            raise RecordingError(f"{path}: in its readings, {why}")
    return tracks


def _at_times(path: Path, name: str, track, t: np.ndarray, max_gap: float) -> np.ndarray:
    """A landmark's poses ``(S, 4, 4)`` at the times ``t``: interpolated between its readings,
    held before the first and after the last (each within ``max_gap`` of the demonstration)."""
    tt, T = track
    if len(tt) > 1 and (tt[0] > t[0] + max_gap or tt[-1] < t[-1] - max_gap):
        raise RecordingError(f"{path}: landmark {name!r} is read from {tt[0]:g} s to {tt[-1]:g} s, not within "
                             f"--max-gap {max_gap:g} s of the demonstration's {t[0]:g}-{t[-1]:g} s")
    out = np.tile(np.eye(4), (len(t), 1, 1))
    if len(tt) == 1:
        out[:] = T[0]
        return out
    tc = np.clip(t, tt[0], tt[-1])
    out[:, :3, 3] = np.stack([np.interp(tc, tt, T[:, i, 3]) for i in range(3)], axis=1)
    out[:, :3, :3] = Slerp(tt, Rotation.from_matrix(T[:, :3, :3]))(tc).as_matrix()
    return out


def _into_limits(q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Each unwrapped joint column ``q (S, d)`` shifted by the whole turns (2 pi) that bring it
    within its limits, when some do: a recorder that reports angles in [0, 2 pi) gives a joint
    at -0.1 rad as 6.18."""
    q = q.copy()
    for j in range(q.shape[1]):
        for k in sorted(range(-3, 4), key=abs):  # no shift first
            shifted = q[:, j] + 2 * np.pi * k
            if (shifted >= lower[j] - LIMIT_TOLERANCE).all() and (shifted <= upper[j] + LIMIT_TOLERANCE).all():
                q[:, j] = shifted
                break
    return q


def _limits(robot: RobotSpec) -> tuple[np.ndarray, np.ndarray]:
    """The robot's joint limits from its URDF (``RecordingError`` when it cannot be loaded)."""
    from lfd.robot.kinematics import KinematicModel, KinematicsError

    try:
        kin = KinematicModel.from_spec(robot)
    except KinematicsError as e:
        raise RecordingError(f"robot {robot.name!r} cannot be loaded: {e}") from e
    return kin.lower.cpu().numpy(), kin.upper.cpu().numpy()


def _trim(q: np.ndarray, tolerance: float) -> slice | None:
    """The samples from the last one at which every joint is still within ``tolerance`` (rad) of
    where it started to the first at which every joint is within it of where it ends: the
    pauses before and after the motion are left out (a tolerance, not a speed, so that sensor
    noise does not count as motion). None when no motion is left between them: the tolerance
    is as large as the motion itself."""
    start = np.flatnonzero(np.abs(q - q[0]).max(axis=1) > tolerance)
    end = np.flatnonzero(np.abs(q - q[-1]).max(axis=1) > tolerance)
    if not len(start) or not len(end):
        return None
    first, last = max(0, int(start[0]) - 1), int(end[-1]) + 1
    return slice(first, last + 1) if last > first else None


def _frame(T_base_frame) -> np.ndarray:
    """``T_base_frame`` as a rigid ``(4, 4)`` float array (a scaled rotation scaled every landmark's
    position), else ``RecordingError``."""
    try:
        T = np.asarray(T_base_frame, dtype=float)
    except (ValueError, TypeError):
        T = None
    if T is None or T.shape != (4, 4) or not np.isfinite(T).all() or bool(not_rigid(T)):
        raise RecordingError(f"T_base_frame must be a rigid transform, a finite (4, 4) matrix with a rotation "
                             f"and [0, 0, 0, 1] as its last row, got {T_base_frame!r}")
    return T


def import_recordings(root: str | Path, robot: RobotSpec, rate: float, task: TaskSpec | None = None,
                      columns: JointColumns | None = None, T_base_frame=None, max_gap: float = 0.5,
                      trim: float = 0.0) -> tuple[DemoSet, list[dict]]:
    """Every recording under ``root`` (``find_recordings``) as one ``DemoSet`` sampled at ``rate``
    Hz, and a report per demonstration (its samples before and after, the seconds trimmed, its
    landmarks held still or tracked). ``T_base_frame (4, 4)``: the landmark CSVs' frame in the
    robot's base frame, a rigid transform (default: they are in the base frame). ``task``: the
    set's task, whose ``dt`` must be the samples' ``1 / rate``. ``RecordingError`` on bad input."""
    if not isinstance(robot, RobotSpec):  # a name gave an AttributeError deep in the column check
        raise TypeError(f"robot must be a RobotSpec (e.g. lfd.robot.robots.BAXTER_LEFT), got {robot!r}")
    if task is not None and not isinstance(task, TaskSpec):
        raise TypeError(f"task must be a TaskSpec or None (lfd.learning.tasks.task_from_name), got {task!r}")
    if columns is not None and not isinstance(columns, JointColumns):  # a dict: AttributeError on .check
        raise TypeError(f"columns must be a JointColumns (JointColumns(joints={{...}}) for a mapping), got "
                        f"{type(columns).__name__}")
    if not all(is_real(v) for v in (rate, max_gap, trim)):  # strings: Python's TypeError from a comparison
        raise RecordingError(f"rate, max_gap and trim must be numbers, got {rate!r}, {max_gap!r}, {trim!r}")
    if not (math.isfinite(rate) and rate > 0) or not max_gap > 0 or not trim >= 0:
        raise RecordingError(f"rate and max_gap must be positive and trim >= 0, got {rate}, {max_gap}, {trim}")
    why = other_task_dt(task.dt, 1.0 / rate) if task is not None else None
    if why:  # the model would plan at task.dt with steps learned from samples 1 / rate apart
        raise RecordingError(f"task {task.name!r}: {why}; at rate={rate:g} Hz the samples are "  # type: ignore[union-attr]
                             f"{1.0 / rate:g} s apart")
    columns = columns or JointColumns()
    columns.check(robot)
    T_base_frame = np.eye(4) if T_base_frame is None else _frame(T_base_frame)
    lower, upper = _limits(robot)
    demos, report, names = [], [], None
    for name, jpath, lpath in find_recordings(root):
        t_raw, q_raw = _joints(jpath, robot, columns, max_gap)
        q_raw = _into_limits(q_raw, lower, upper)
        out = (q_raw < lower - LIMIT_TOLERANCE) | (q_raw > upper + LIMIT_TOLERANCE)
        if out.any():
            i, j = (int(x) for x in np.argwhere(out)[0])
            raise RecordingError(f"{jpath}: row {i + 2}: joint {robot.joint_names[j]} = {q_raw[i, j]:.4g} rad is "
                                 f"outside its URDF limits [{lower[j]:.4g}, {upper[j]:.4g}]")
        if lpath is None:
            raise RecordingError(f"{jpath}: no landmark recording beside it ({name}/landmarks.csv or "
                                 f"{name}_landmarks.csv)")
        tracks = _landmark_tracks(lpath, T_base_frame, max_gap)
        if names is None:
            names = tuple(tracks)
        elif set(tracks) != set(names):
            raise RecordingError(f"{lpath}: landmarks {sorted(tracks)} differ from the first recording's "
                                 f"{sorted(names)}")
        keep = _trim(q_raw, trim) if trim else slice(0, len(t_raw))
        if keep is None:
            span = float(np.abs(q_raw - q_raw[0]).max())
            raise RecordingError(f"{jpath}: no motion is left once the pauses are trimmed with a tolerance of "
                                 f"{trim:g} rad (no joint moves more than {span:.3g} rad from where it "
                                 "starts): lower --trim-pauses")
        t0, t1 = t_raw[keep][0], t_raw[keep][-1]
        if t1 - t0 > MAX_DEMO_S:  # (a stray time stamp within a huge --max-gap asked for terabytes)
            raise RecordingError(f"{jpath}: the joints' readings span {t1 - t0:.4g} s, more than a demonstration "
                                 f"of {MAX_DEMO_S:g} s: a time stamp is off (in another unit?)")
        t = t0 + np.arange(int(math.floor((t1 - t0) * rate + 1e-9)) + 1) / rate  # (S,)
        if len(t) < 2:  # was reported as an arm that never moved
            raise RecordingError(f"{jpath}: {len(t_raw)} reading(s) over {t1 - t0:.3g} s, shorter than one "
                                 f"sample interval at {rate:g} Hz: record longer or raise --rate")
        q = np.stack([np.interp(t, t_raw, q_raw[:, j]) for j in range(q_raw.shape[1])], axis=1)
        # (S, Z, 4, 4): positions interpolated linearly between readings already checked for their
        # distance and speed (_landmark_tracks), so the samples are no farther and no faster
        poses = np.stack([_at_times(lpath, n, tracks[n], t, max_gap) for n in names], axis=1)
        still = all(len(tracks[n][0]) == 1 for n in names)
        demos.append(Demonstration(q=q, dt=1.0 / rate, landmarks=poses[0] if still else poses, name=name))
        report.append({"name": name, "raw_samples": len(t_raw), "samples": len(t),
                       "trimmed_start_s": round(float(t0 - t_raw[0]), 3), "trimmed_end_s": round(float(t_raw[-1] - t1), 3),
                       "landmarks": "held still" if still else "tracked"})
    assert names is not None  # find_recordings found at least one
    why = unusable_demos([d.q for d in demos], [d.name for d in demos])
    if why:
        raise RecordingError(f"{root}: {why}")
    ds = DemoSet(demos=tuple(demos), joint_names=robot.joint_names, landmark_names=names, robot=robot, task=task)
    return ds, report
