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

Real recorders leave dropouts, repeated and near-simultaneous stamps, outliers and jitter: each
landmark's readings and the joints are cleaned first (``lfd.io.cleaning``, what was done is
reported), then every demonstration is resampled to one rate (joints linearly) from its first
joint sample. What a recording must satisfy, each refused with one line naming the file and
row (``RecordingError``): every row has the header's number of fields, the columns exist, every
value is a number (or, for a joint or a pose, a missing reading: empty, ``nan``, ``NA``),
time never goes back, no gap between the readings kept is longer than ``max_gap``, quaternions
are unit (within ``QUAT_TOLERANCE``) or a dropout, every demonstration names the same
landmarks, every landmark has a reading within ``max_gap`` of both ends of each demonstration,
none is farther than ``lfd.learning.demo_checks.MAX_LANDMARK_DISTANCE`` (20 m) from the robot's
base (another unit), and none moves faster than 5 m/s once lone outliers are dropped. Pauses
at the start and end (every joint within ``trim`` rad of where it starts or ends) can be
trimmed, and are reported. Every reader makes ``lfd.io.raw.RawRecording`` objects
(``read_csv_recording`` here, ``lfd.io.rosbag`` for bags) and ``import_raw`` turns them into the
``DemoSet`` and its report; ``import_recordings`` does it for a folder of CSVs, and
``lfd.io.import_csv`` (``lfd-import``) writes the set.
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

from lfd.io.cleaning import (
    DROPOUT_MODES,
    OUTLIER_MODES,
    QUAT_TOLERANCE,
    CleanJoints,
    CleanTrack,
    clean_joints,
    clean_track,
)
from lfd.io.raw import RawRecording, RawTrack, RecordingError
from lfd.learning.demo_checks import LIMIT_TOLERANCE, other_task_dt, unusable_demos
from lfd.learning.demoset import Demonstration, DemoSet
from lfd.learning.tasks import TaskSpec, is_real
from lfd.robot.robots import RobotSpec
from lfd.robot.se3 import not_rigid

__all__ = ["LANDMARK_COLUMNS", "MAX_DEMO_S", "QUAT_TOLERANCE", "ImportSettings", "JointColumns", "RecordingError",
           "find_recordings", "import_raw", "import_recordings", "read_csv_recording"]

LANDMARK_COLUMNS = ("time", "name", "x", "y", "z", "qx", "qy", "qz", "qw")
MAX_DEMO_S = 3600.0  # s: a demonstration longer than an hour is a time stamp in error (a task takes seconds)


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
    Every visible folder is a demonstration: one without a ``joints.csv`` file is refused (a
    ``joints.csv.txt``, a folder or a looping link of that name: the set would lose it without a
    word), and so is a recording's file that is not a regular file, a ``DEMO_landmarks.csv``
    without its ``DEMO_joints.csv`` and a file named like a recording that is not one.
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

    def regular(p: Path | None, what: str) -> Path | None:
        """``p`` when it is a readable regular file (None when absent); refused when it is a folder,
        a broken or looping link, or another kind of entry (a demonstration would vanish)."""
        if p is None:
            return None
        try:
            if p.is_file():
                return p
        except OSError as e:  # a link loop on some Python versions
            raise RecordingError(f"{p}: {what} cannot be opened ({e})") from e
        kind = "a folder" if p.is_dir() else "a broken or looping link" if p.is_symlink() else "not a regular file"
        raise RecordingError(f"{p}: {what} is {kind}, not a file")

    top = visible(root)
    found = []
    for d in (p for p in top.values() if p.is_dir()):
        inside = visible(d)
        joints = regular(inside.get("joints.csv"), "the joint recording")
        if joints is None:  # a folder in the recordings is a demonstration: one without its file is an error
            held = ", ".join(sorted(p.name for p in inside.values())) or "nothing"
            raise RecordingError(f"{d}: a folder without a joints.csv (it holds: {held}); name the joint "
                                 f"recording joints.csv, or move the folder out of {root}")
        found.append((d.name, joints, regular(inside.get("landmarks.csv"), "the landmark recording")))
    for low, f in top.items():
        if low.endswith("_joints.csv"):
            name = f.name[: -len("_joints.csv")]
            joints = regular(f, "the joint recording")
            assert joints is not None  # (f exists)
            found.append((name, joints, regular(top.get(f"{name.lower()}_landmarks.csv"), "the landmark recording")))
        elif low.endswith("_landmarks.csv"):
            if low[: -len("_landmarks.csv")] + "_joints.csv" not in top:
                raise RecordingError(f"{f}: a landmark recording without its joint recording "
                                     f"{f.name[: -len('_landmarks.csv')]}_joints.csv")
        elif ("_joints.csv" in low or "_landmarks.csv" in low) and not f.is_dir():  # joints.csv.txt, .csv.bak
            raise RecordingError(f"{f}: named like a recording but not one (DEMO_joints.csv, DEMO_landmarks.csv); "
                                 f"rename it or move it out of {root}")
    found.sort(key=lambda r: (r[0].lower(), r[0]))
    for (n1, j1, _), (n2, j2, _) in itertools.pairwise(found):
        if n1.lower() == n2.lower():
            raise RecordingError(f"{j1} and {j2}: two recordings named {n1!r}; keep one of them")
    if not found:
        raise RecordingError(f"{root}: no recordings (DEMO/joints.csv or DEMO_joints.csv)")
    return found


MISSING = frozenset({"", "nan", "na", "n/a", "null", "none"})  # (lower case) a reading the recorder did not have


def _read_csv(path: Path) -> tuple[list[str], list[list[str]], np.ndarray]:
    """The header, the data rows and each row's line in the file ``(rows,)`` (1-based: the
    header is line 1 when the file starts with it). Blank lines are skipped; a row with another
    number of fields than the header (a truncated last row, values shifted under the wrong
    columns) is refused."""
    try:
        # utf-8-sig: a spreadsheet's byte-order mark is not part of the first column's name
        with path.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.reader(fh)
            numbered = [(reader.line_num, r) for r in reader if r and any(c.strip() for c in r)]
    except UnicodeDecodeError as e:
        raise RecordingError(f"{path}: not UTF-8 text ({e}); save it as 'CSV UTF-8'") from e
    except (OSError, csv.Error) as e:
        raise RecordingError(f"{path}: cannot be read as CSV ({e})") from e
    if len(numbered) < 2:
        raise RecordingError(f"{path}: needs a header row and at least one data row")
    header = [c.strip() for c in numbered[0][1]]
    other = next((sep for sep in ";\t|" if len(header) == 1 and sep in header[0]), None)
    if other is not None:  # a spreadsheet in a locale whose decimal mark is ','
        raise RecordingError(f"{path}: the header {header[0]!r} is one column: the fields are separated by "
                             f"{other!r}, not ','; save it as comma-separated CSV, with '.' as the decimal mark")
    for line, r in numbered[1:]:
        if len(r) != len(header):  # read by position, a row of other length puts values under other columns
            why = "fewer (a truncated row: the recorder stopped while writing?)" if len(r) < len(header) else "more"
            raise RecordingError(f"{path}: row {line} has {len(r)} fields, the header {len(header)}: {why}")
    return header, [r for _, r in numbered[1:]], np.array([line for line, _ in numbered[1:]], dtype=np.int64)


def _numbers(path: Path, header: list[str], rows: list[list[str]], lines: np.ndarray, columns,
             missing_ok=()) -> np.ndarray:
    """``(rows, len(columns))`` floats of the named columns. A missing column, or a value that is
    not a finite number, is refused with its row; in the columns ``missing_ok`` an empty cell or
    ``nan`` / ``NA`` / ``null`` is a missing reading (NaN), for the cleaning to bridge."""
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
            cell = r[k].strip()
            if columns[j] in missing_ok and cell.lower() in MISSING:
                out[i, j] = math.nan
                continue
            try:
                out[i, j] = float(cell)
            except ValueError:
                out[i, j] = math.nan
            if not math.isfinite(out[i, j]):
                raise RecordingError(f"{path}: row {int(lines[i])}, column {columns[j]!r}: {r[k]!r} is not a "
                                     f"finite number")
    return out


def read_csv_recording(name: str, joints_csv: Path, landmarks_csv: Path | None, robot: RobotSpec,
                       cols: JointColumns | None = None) -> RawRecording:
    """One demonstration's CSV files as a ``RawRecording``: the joints in ``robot``'s order and
    radians (unwrapped, as recorded otherwise), each landmark's readings as written."""
    cols = cols or JointColumns()
    header, rows, lines = _read_csv(joints_csv)
    joints = [cols.column(j) for j in robot.joint_names]
    a = _numbers(joints_csv, header, rows, lines, [cols.time, *joints], missing_ok=set(joints))
    t, q = a[:, 0], a[:, 1:]
    if cols.degrees:
        q = np.deg2rad(q)
    ok = np.isfinite(q).all(axis=1)
    q[ok] = np.unwrap(q[ok], axis=0)  # across missing rows too
    if landmarks_csv is None:
        raise RecordingError(f"{joints_csv}: no landmark recording beside it ({name}/landmarks.csv or "
                             f"{name}_landmarks.csv)")
    header, rows, llines = _read_csv(landmarks_csv)
    if "name" not in header:
        raise RecordingError(f"{landmarks_csv}: missing column(s) ['name'] (header: {header})")
    k = header.index("name")
    pose_cols = [c for c in LANDMARK_COLUMNS if c not in ("time", "name")]
    a = _numbers(landmarks_csv, header, rows, llines, ["time", *pose_cols], missing_ok=set(pose_cols))
    names = np.array([r[k].strip() for r in rows])
    if (names == "").any():
        raise RecordingError(f"{landmarks_csv}: row {int(llines[np.flatnonzero(names == '')[0]])}: empty landmark name")
    tracks = {}
    for lm in dict.fromkeys(names.tolist()):  # in order of first appearance
        sel = np.flatnonzero(names == lm)
        tracks[lm] = RawTrack(t=a[sel, 0], pose=a[sel, 1:], where=llines[sel])
    return RawRecording(name=name, t=t, q=q, tracks=tracks, joint_source=str(joints_csv),
                        landmark_source=str(landmarks_csv), joint_where=lines, unit="row")


def _at_times(source: str, name: str, track: CleanTrack, t: np.ndarray, max_gap: float) -> np.ndarray:
    """A landmark's poses ``(S, 4, 4)`` at the times ``t``: interpolated between its readings,
    held before the first and after the last (each within ``max_gap`` of the demonstration)."""
    tt, T = track.t, track.T_base_landmark
    first, last = track.span
    if len(tt) > 1 and (first > t[0] + max_gap or last < t[-1] - max_gap):
        clocks = (" and never while the joints are: the two files' clocks disagree (another clock, or another "
                  "unit)?" if first > t[-1] or last < t[0] else "")
        raise RecordingError(f"{source}: landmark {name!r} is read from {first:g} s to {last:g} s, not within "
                             f"--max-gap {max_gap:g} s of the demonstration's {t[0]:g}-{t[-1]:g} s{clocks}")
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


@dataclass(frozen=True)
class ImportSettings:
    """How recordings become a demonstration set.

    rate : samples per second after resampling (Hz).
    max_gap : the longest time (s) allowed between two readings kept (dropouts bridged included).
    trim : leave out the start (end) while every joint stays within ``trim`` rad of where it
        starts (ends); 0 keeps everything.
    dropouts : ``'bridge'`` (missing readings are left out and bridged) or ``'refuse'``.
    outliers : ``'drop'`` (an impossible jump is dropped and reported) or ``'refuse'``.
    smooth : the Savitzky-Golay window (s) for tracked landmarks; 0: not smoothed.
    T_base_frame : (4, 4) the landmark readings' frame in the robot's base frame (default, or
        None: the base itself).
    task : the set's task, whose ``dt`` must be ``1 / rate`` (None: none).
    """

    rate: float = 10.0
    max_gap: float = 0.5
    trim: float = 0.0
    dropouts: str = "bridge"
    outliers: str = "drop"
    smooth: float = 0.0
    T_base_frame: np.ndarray = field(default_factory=lambda: np.eye(4))
    task: TaskSpec | None = None

    def __post_init__(self):
        if not all(is_real(v) for v in (self.rate, self.max_gap, self.trim, self.smooth)):
            raise RecordingError(f"rate, max_gap, trim and smooth must be numbers, got {self.rate!r}, "
                                 f"{self.max_gap!r}, {self.trim!r}, {self.smooth!r}")
        if not (math.isfinite(self.rate) and self.rate > 0) or not self.max_gap > 0 or not self.trim >= 0 \
                or not (math.isfinite(self.smooth) and self.smooth >= 0):
            raise RecordingError(f"rate and max_gap must be positive, trim and smooth >= 0, got {self.rate}, "
                                 f"{self.max_gap}, {self.trim}, {self.smooth}")
        if self.dropouts not in DROPOUT_MODES or self.outliers not in OUTLIER_MODES:
            raise RecordingError(f"dropouts must be one of {DROPOUT_MODES} and outliers one of {OUTLIER_MODES}, "
                                 f"got {self.dropouts!r}, {self.outliers!r}")
        if self.task is not None and not isinstance(self.task, TaskSpec):
            raise TypeError(f"task must be a TaskSpec or None (lfd.learning.tasks.task_from_name), got {self.task!r}")
        why = other_task_dt(self.task.dt, 1.0 / self.rate) if self.task is not None else None
        if why:  # the model would plan at task.dt with steps learned from samples 1 / rate apart
            raise RecordingError(f"task {self.task.name!r}: {why}; at rate={self.rate:g} Hz the samples are "  # type: ignore[union-attr]
                                 f"{1.0 / self.rate:g} s apart")
        object.__setattr__(self, "T_base_frame", np.eye(4) if self.T_base_frame is None else _frame(self.T_base_frame))


def _joint_samples(raw: RawRecording, robot: RobotSpec, limits, settings: ImportSettings) -> CleanJoints:
    """The joints cleaned (``lfd.io.cleaning.clean_joints``), moved into and checked against the limits."""
    lower, upper = limits
    joints = clean_joints(raw.t, raw.q, raw.joint_where, raw.joint_source, raw.unit, settings.max_gap,
                          settings.dropouts)
    q = _into_limits(joints.q, lower, upper)
    out = (q < lower - LIMIT_TOLERANCE) | (q > upper + LIMIT_TOLERANCE)
    if out.any():
        i, j = (int(x) for x in np.argwhere(out)[0])
        row = int(raw.joint_where[np.flatnonzero(raw.t == joints.t[i])[-1]])
        raise RecordingError(f"{raw.joint_source}: {raw.unit} {row}: joint {robot.joint_names[j]} = {q[i, j]:.4g} rad "
                             f"is outside its URDF limits [{lower[j]:.4g}, {upper[j]:.4g}]")
    return CleanJoints(joints.t, q, joints.report)


def _one_demo(raw: RawRecording, robot: RobotSpec, limits, settings: ImportSettings, names):
    """``(Demonstration, report dict, landmark names)`` of one recording."""
    joints = _joint_samples(raw, robot, limits, settings)
    t_raw, q_raw = joints.t, joints.q
    tracks = {n: clean_track(n, tr.t, tr.pose, tr.where, raw.landmark_source, raw.unit, settings.T_base_frame,
                             settings.max_gap, settings.dropouts, settings.outliers, settings.smooth)
              for n, tr in raw.tracks.items()}
    if not tracks:
        raise RecordingError(f"{raw.landmark_source or raw.name}: no landmark readings")
    if names is not None and set(tracks) != set(names):
        raise RecordingError(f"{raw.landmark_source}: landmarks {sorted(tracks)} differ from the first recording's "
                             f"{sorted(names)}")
    names = tuple(tracks) if names is None else names
    keep = _trim(q_raw, settings.trim) if settings.trim else slice(0, len(t_raw))
    if keep is None:
        span = float(np.abs(q_raw - q_raw[0]).max())
        raise RecordingError(f"{raw.joint_source}: no motion is left once the pauses are trimmed with a tolerance of "
                             f"{settings.trim:g} rad (no joint moves more than {span:.3g} rad from where it "
                             "starts): lower --trim-pauses")
    t0, t1 = t_raw[keep][0], t_raw[keep][-1]
    if t1 - t0 > MAX_DEMO_S:  # (a stray time stamp within a huge --max-gap asked for terabytes)
        raise RecordingError(f"{raw.joint_source}: the joints' readings span {t1 - t0:.4g} s, more than a "
                             f"demonstration of {MAX_DEMO_S:g} s: a time stamp is off (in another unit?)")
    rate = settings.rate
    t = t0 + np.arange(int(math.floor((t1 - t0) * rate + 1e-9)) + 1) / rate  # (S,)
    if len(t) < 2:  # was reported as an arm that never moved
        raise RecordingError(f"{raw.joint_source}: {len(t_raw)} reading(s) over {t1 - t0:.3g} s, shorter than one "
                             f"sample interval at {rate:g} Hz: record longer or raise --rate")
    q = np.stack([np.interp(t, t_raw, q_raw[:, j]) for j in range(q_raw.shape[1])], axis=1)
    # (S, Z, 4, 4): interpolated between readings already checked for their distance and speed
    poses = np.stack([_at_times(raw.landmark_source, n, tracks[n], t, settings.max_gap) for n in names], axis=1)
    still = all(len(tracks[n].t) == 1 for n in names)
    origin = float(raw.t[0])  # the report's times are from the recording's first joint reading
    report = {"name": raw.name, "raw_samples": len(raw.t), "unit": raw.unit, "samples": len(t),
              "trimmed_start_s": round(float(t0 - t_raw[0]), 3), "trimmed_end_s": round(float(t_raw[-1] - t1), 3),
              "start_s": round(float(t0) - origin, 6), "end_s": round(float(t_raw[-1]) - origin, 6),
              "landmarks": "held still" if still else "tracked",
              "joints": {**joints.report.as_dict(),
                         "dropout_times": [round(x - origin, 4) for x in joints.report.dropout_times]},
              "tracks": {n: {**tracks[n].report.as_dict(),
                             "dropout_times": [round(x - origin, 4) for x in tracks[n].report.dropout_times],
                             "outlier_times": [round(x - origin, 4) for x in tracks[n].report.outlier_times]}
                         for n in names}}
    demo = Demonstration(q=q, dt=1.0 / rate, landmarks=poses[0] if still else poses, name=raw.name)
    return demo, report, names


def import_raw(raws, robot: RobotSpec, settings: ImportSettings, source: str = "") -> tuple[DemoSet, list[dict]]:
    """Recordings read from any source (``RawRecording``, e.g. ``read_csv_recording`` or
    ``lfd.io.rosbag.read_bag``) as one ``DemoSet`` sampled at ``settings.rate``, and a report per
    demonstration: its samples before and after, the seconds trimmed, and what the cleaning did to
    the joints and to each landmark (``lfd.io.cleaning``: dropouts bridged, repeated and
    near-simultaneous readings merged, outliers dropped, the tracker's rate, jitter, smoothing).
    ``source`` names the recordings in messages about the whole set. ``RecordingError`` on bad input."""
    if not isinstance(robot, RobotSpec):  # a name gave an AttributeError deep in the column check
        raise TypeError(f"robot must be a RobotSpec (e.g. lfd.robot.robots.BAXTER_LEFT), got {robot!r}")
    if not isinstance(settings, ImportSettings):
        raise TypeError(f"settings must be an ImportSettings, got {type(settings).__name__}")
    raws = list(raws)
    if not raws:
        raise RecordingError(f"{source}: no recordings")
    for raw in raws:
        if raw.q.shape[1] != len(robot.joint_names):
            raise RecordingError(f"{raw.joint_source}: {raw.q.shape[1]} joint columns, robot {robot.name!r} has "
                                 f"{len(robot.joint_names)}")
    limits = _limits(robot)
    demos, report, names = [], [], None
    for raw in raws:
        demo, rep, names = _one_demo(raw, robot, limits, settings, names)
        demos.append(demo)
        report.append(rep)
    assert names is not None
    why = unusable_demos([d.q for d in demos], [d.name for d in demos])
    if why:
        raise RecordingError(f"{source}: {why}")
    ds = DemoSet(demos=tuple(demos), joint_names=robot.joint_names, landmark_names=names, robot=robot,
                 task=settings.task)
    return ds, report


def import_recordings(root: str | Path, robot: RobotSpec, rate: float, task: TaskSpec | None = None,
                      columns: JointColumns | None = None, T_base_frame=None, max_gap: float = 0.5,
                      trim: float = 0.0, dropouts: str = "bridge", outliers: str = "drop",
                      smooth: float = 0.0) -> tuple[DemoSet, list[dict]]:
    """Every CSV recording under ``root`` (``find_recordings``) as one ``DemoSet`` (``import_raw``;
    the arguments are ``ImportSettings``'s). ``columns``: how the joint CSVs name their columns."""
    if not isinstance(robot, RobotSpec):
        raise TypeError(f"robot must be a RobotSpec (e.g. lfd.robot.robots.BAXTER_LEFT), got {robot!r}")
    if columns is not None and not isinstance(columns, JointColumns):  # a dict: AttributeError on .check
        raise TypeError(f"columns must be a JointColumns (JointColumns(joints={{...}}) for a mapping), got "
                        f"{type(columns).__name__}")
    settings = ImportSettings(rate=rate, max_gap=max_gap, trim=trim, dropouts=dropouts, outliers=outliers,
                              smooth=smooth, T_base_frame=T_base_frame, task=task)
    columns = columns or JointColumns()
    columns.check(robot)
    raws = [read_csv_recording(name, jpath, lpath, robot, columns) for name, jpath, lpath in find_recordings(root)]
    return import_raw(raws, robot, settings, str(root))
