"""ROS bags read into ``RawRecording``: ROS 1 ``.bag`` files, ROS 2 bag folders (``metadata.yaml``
with sqlite3 or mcap storage) and bare ROS 2 ``.mcap`` files, through ``rosbags`` (pure Python, no
ROS installation; the ``[ros]`` extra: ``pip install ".[ros]"``).

* **Joints**: a ``sensor_msgs/JointState`` topic. Each message's ``name`` list maps its ``position``
  values to the robot's joints, in any order; the other joints it carries (the other arm, the
  grippers) are ignored. A message naming some but not all of the robot's joints is a row of NaN
  (a dropout, counted by the cleaning); one naming none of them (another publisher's on the same
  topic, a gripper's) is no reading of the arm and is skipped.
* **Landmarks from tf** (``landmark_frames``, through ``lfd.io.tf_tree``): the transforms of ``/tf``
  and ``/tf_static`` are kept per edge (parent -> child frame). A landmark frame is chained to
  ``base_frame`` through their common ancestor in the tf tree (any depth, either direction). It
  is read whenever a moving transform on its chain is published, at that transform's stamp,
  with the chain's other moving transforms interpolated at that time (positions linearly,
  orientations by slerp, as tf2's lookup does) and each static one as last published; only
  while every moving transform of the chain has readings on both sides. A chain of static
  transforms only is read once.
* **Landmarks from topics** (``landmark_topics``, ``{name: topic}``): ``geometry_msgs/PoseStamped``
  poses in their ``header.frame_id``, chained to the base frame through tf at the message's stamp
  when that frame is not the base (a NaN row where tf has no reading at that time).
* **Times**: header stamps, the sensor's clock. A stream (a topic) whose stamps are all zero
  (unset) is timed by the bag's receive times instead, and a note says so.

Readings stay raw (``lfd.io.raw``): dropouts are NaN rows and time is as recorded; poses are
``x, y, z, qx, qy, qz, qw`` in the base frame (so ``T_base_frame`` is the identity for bags). A
reading's ``where`` is its message's number on its topic (1-based). ``find_bags`` finds the bags
of an input (one per demonstration), ``split_on_pause`` cuts one recording into several, and
``add_bag_arguments`` / ``raws_from_args`` are what ``lfd-import`` uses. Errors a user can fix
are ``RecordingError`` naming the bag, the topic or frame and what is wrong.
"""

from __future__ import annotations

import argparse
import itertools
import math
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lfd.io.raw import RawRecording, RawTrack, RecordingError
from lfd.io.tf_tree import TF_TOPICS, TfTree, compose

__all__ = ["BAG_OPTIONS", "PAUSE_TOLERANCE", "add_bag_arguments", "bag_options_given", "find_bags",
           "is_bag_input", "raws_from_args", "read_bag", "split_on_pause"]

JOINT_STATE = "sensor_msgs/msg/JointState"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")  # (ROS 1's old tf package: tf/tfMessage)
PAUSE_TOLERANCE = 0.02  # rad: --pause-tolerance's default (a joint encoder's noise stays well within)
# the options add_bag_arguments adds, by their argparse dest (for refusing them with CSV input)
BAG_OPTIONS = {"joint_topic": "--joint-topic", "landmark_frames": "--landmark-frames", "base_frame": "--base-frame",
               "landmark_topics": "--landmark-topics", "split_on_pause": "--split-on-pause",
               "pause_tolerance": "--pause-tolerance"}


# ---------------------------------------------------------------------------------------------
# finding bags


def _kind(path: Path) -> str | None:
    """``'ros1'`` (a ``.bag`` file), ``'mcap'`` (a bare ``.mcap`` file), ``'ros2'`` (a folder with
    ``metadata.yaml``) or None."""
    if path.is_file():
        return {".bag": "ros1", ".mcap": "mcap"}.get(path.suffix.lower())
    if path.is_dir() and (path / "metadata.yaml").is_file():
        return "ros2"
    return None


def is_bag_input(path: str | Path) -> bool:
    """Whether ``lfd-import``'s input is bags: a ``.bag`` or ``.mcap`` file, a ROS 2 bag folder, or a
    folder holding at least one of those (``find_bags`` then refuses anything else in it)."""
    path = Path(path)
    if _kind(path) is not None:
        return True
    return path.is_dir() and any(_kind(p) is not None for p in path.iterdir() if not p.name.startswith("."))


def _bag_name(bag: Path) -> str:
    """The demonstration's name: the file's stem, or the ROS 2 bag folder's name."""
    return bag.name if bag.is_dir() else bag.stem


def find_bags(path: str | Path) -> list[Path]:
    """The bags of ``path``, one per demonstration: ``[path]`` for a ``.bag`` file, a ``.mcap`` file or
    a ROS 2 bag folder (``metadata.yaml``); for a folder of those, each of them, sorted by name
    (hidden entries skipped). Anything else in such a folder, or two bags of one name (``a.bag``
    and ``a.mcap``), is refused with a ``RecordingError`` naming it."""
    path = Path(path)
    if not path.exists():
        raise RecordingError(f"{path}: no such bag or folder of bags")
    if _kind(path) is not None:
        return [path]
    if not path.is_dir():
        raise RecordingError(f"{path}: not a ROS bag (a .bag file, a .mcap file or a ROS 2 bag folder with "
                             "metadata.yaml)")
    bags: list[Path] = []
    names: dict[str, Path] = {}
    for p in sorted(path.iterdir(), key=lambda p: (p.name.lower(), p.name)):
        if p.name.startswith("."):
            continue
        if _kind(p) is None:
            raise RecordingError(f"{p}: not a ROS bag (a .bag file, a .mcap file or a ROS 2 bag folder with "
                                 f"metadata.yaml) in the folder of bags {path}; move it out")
        low = _bag_name(p).lower()
        if low in names:
            raise RecordingError(f"{names[low]} and {p}: two bags named {_bag_name(p)!r} (in any case); keep one")
        names[low] = p
        bags.append(p)
    if not bags:
        raise RecordingError(f"{path}: no bags in this folder (.bag, .mcap or ROS 2 bag folders)")
    return bags


# ---------------------------------------------------------------------------------------------
# opening a bag with rosbags


def _rosbags_errors() -> tuple[type[BaseException], ...]:
    """The errors rosbags raises for a bag it cannot read (damaged, truncated, unsupported); with
    those its parsers let through from damaged bytes (a cut record, a bad string, a huge length)."""
    import struct

    import apsw
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Ros1Error
    from rosbags.rosbag2 import ReaderError as Ros2Error
    from rosbags.serde import SerdeError
    from rosbags.typesys import TypesysError

    return (AnyReaderError, Ros1Error, Ros2Error, SerdeError, TypesysError, apsw.Error, struct.error,
            UnicodeDecodeError, OverflowError)


@contextmanager
def _open(bag: Path) -> Iterator[Any]:
    """An open ``rosbags.highlevel.AnyReader`` of one bag; ``RecordingError`` when rosbags is not
    installed or the bag cannot be read."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError as e:
        raise RecordingError(f"{bag}: reading ROS bags needs the rosbags package ({e}): "
                             'pip install ".[ros]" (or pip install rosbags)') from e
    kind = _kind(bag)
    if kind is None:
        raise RecordingError(f"{bag}: not a ROS bag (a .bag file, a .mcap file or a ROS 2 bag folder with "
                             "metadata.yaml)")
    if kind == "ros1" and bag.suffix != ".bag":  # rosbags tells ROS 1 from ROS 2 by this suffix
        raise RecordingError(f"{bag}: rosbags reads a ROS 1 bag only with the suffix '.bag' in lower case; "
                             "rename it")
    errors = _rosbags_errors()
    # a ROS 2 bag written without message definitions is read with Humble's standard messages
    reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
    try:
        reader.open()
    except errors as e:
        raise RecordingError(f"{bag}: cannot be read as a ROS bag ({type(e).__name__}: {e})") from e
    try:
        yield reader
    finally:
        reader.close()


def _topic_list(types: Mapping[str, str | None]) -> str:
    return ", ".join(f"{t} ({m})" for t, m in sorted(types.items())) or "none"


def _check_topic(bag: Path, types: Mapping[str, str | None], topic: str, wanted: Sequence[str], what: str) -> None:
    if topic not in types:
        raise RecordingError(f"{bag}: {what} topic {topic!r} is not in the bag (its topics: {_topic_list(types)})")
    if types[topic] not in wanted:
        raise RecordingError(f"{bag}:{topic}: messages of type {types[topic]}, not {' or '.join(wanted)} "
                             f"(the {what} topic)")


def _joint_topic(bag: Path, types: Mapping[str, str | None], joint_topic: str | None) -> str:
    """``joint_topic``, or the bag's only ``JointState`` topic when it is None."""
    if joint_topic is not None:
        _check_topic(bag, types, joint_topic, (JOINT_STATE,), "joint")
        return joint_topic
    found = sorted(t for t, m in types.items() if m == JOINT_STATE)
    if len(found) != 1:
        raise RecordingError(f"{bag}: {len(found)} {JOINT_STATE} topics ({', '.join(found) or 'none'}): name the "
                             f"arm's with --joint-topic (the bag's topics: {_topic_list(types)})")
    return found[0]


# ---------------------------------------------------------------------------------------------
# the messages of one bag


@dataclass
class _Stream:
    """The readings of one topic: header stamps and receive times (s), message numbers, payloads."""

    topic: str
    stamp: list = field(default_factory=list)
    recv: list = field(default_factory=list)
    where: list = field(default_factory=list)
    data: list = field(default_factory=list)

    def add(self, stamp, recv_ns: int, where: int, data) -> None:
        self.stamp.append(stamp.sec + stamp.nanosec * 1e-9)
        self.recv.append(recv_ns * 1e-9)
        self.where.append(where)
        self.data.append(data)

    def times(self, source: str, notes: list[str]) -> np.ndarray:
        """The header stamps, or the receive times when every stamp is zero (with a note)."""
        stamp = np.asarray(self.stamp, dtype=float)
        if len(stamp) and not stamp.any():
            notes.append(f"{source}: every header stamp is zero (unset): the bag's receive times are used")
            return np.asarray(self.recv, dtype=float)
        return stamp


def _frame_id(name: str) -> str:
    """A tf frame's name without ROS 1's leading '/'."""
    return name.strip().lstrip("/")


def _pose7(position, orientation) -> list[float]:
    return [position.x, position.y, position.z, orientation.x, orientation.y, orientation.z, orientation.w]


class _JointRows:
    """``JointState`` messages as rows in the robot's joint order (a message's name order cached)."""

    def __init__(self, joint_names: Sequence[str]):
        self.joint_names = list(joint_names)
        self.seen: dict[str, None] = {}
        self._index: dict[tuple, np.ndarray | None] = {}

    def row(self, msg) -> np.ndarray | None:
        """``(d,)`` angles, NaN for a joint the message lacks; None when it names none of them."""
        names = tuple(msg.name)
        if names not in self._index:
            self.seen.update(dict.fromkeys(names))
            pos = {n: i for i, n in enumerate(names)}
            idx = np.array([pos.get(j, -1) for j in self.joint_names])
            self._index[names] = None if (idx < 0).all() else idx
        cols = self._index[names]
        if cols is None:
            return None
        position = np.asarray(msg.position, dtype=float)
        ok = (cols >= 0) & (cols < len(position))  # (a driver that sends no positions: NaN)
        out = np.full(len(cols), np.nan)
        out[ok] = position[cols[ok]]
        return out


def _read_streams(reader, bag: Path, joint_topic: str, pose_topics: Sequence[str], tf_topics: Sequence[str],
                  joints: _JointRows) -> dict[str, _Stream]:
    """Every reading of the topics wanted, in the bag's order. JointState: a ``(d,)`` row; tf: one
    reading per transform, ``(parent, child, pose (7,))``; PoseStamped: ``(frame_id, pose (7,))``."""
    wanted = {joint_topic, *pose_topics, *tf_topics}
    streams = {t: _Stream(t) for t in wanted}
    count = dict.fromkeys(wanted, 0)
    connections = [c for c in reader.connections if c.topic in wanted]
    last = "before its first message"
    # (rosbags checks a damaged ROS 1 record's time with an assert)
    errors: tuple[type[BaseException], ...] = (*_rosbags_errors(), AssertionError)
    try:
        for conn, recv_ns, data in reader.messages(connections=connections):
            topic = conn.topic
            count[topic] += 1
            n, s = count[topic], streams[topic]
            last = f"at message {n} of {topic}"
            msg = reader.deserialize(data, conn.msgtype)
            if topic == joint_topic:
                row = joints.row(msg)
                if row is not None:
                    s.add(msg.header.stamp, recv_ns, n, row)
            elif topic in tf_topics:
                for tr in msg.transforms:
                    s.add(tr.header.stamp, recv_ns, n, (_frame_id(tr.header.frame_id), _frame_id(tr.child_frame_id),
                                                        _pose7(tr.transform.translation, tr.transform.rotation)))
            else:
                s.add(msg.header.stamp, recv_ns, n, (_frame_id(msg.header.frame_id),
                                                     _pose7(msg.pose.position, msg.pose.orientation)))
            last = f"after message {n} of {topic}"
    except errors as e:
        raise RecordingError(f"{bag}: damaged {last} ({type(e).__name__}: {e})") from e
    return streams


# ---------------------------------------------------------------------------------------------
# read_bag


def _pose_track(bag: Path, topic: str, s: _Stream, base: str | None, tree: TfTree | None, notes: list[str]) \
        -> RawTrack:
    """A ``PoseStamped`` topic's readings in the base frame."""
    t = s.times(f"{bag.name}:{topic}", notes)
    pose = np.array([d[1] for d in s.data], dtype=float).reshape(-1, 7)
    frames = np.array([d[0] for d in s.data], dtype=object)
    if base is None:
        if len(set(frames)) > 1:
            raise RecordingError(f"{bag}:{topic}: poses in frames {sorted(set(frames))}: name the robot's base "
                                 "frame with --base-frame to chain them to it through tf")
        if len(frames):
            notes.append(f"{bag.name}:{topic}: poses in frame {frames[0]!r}, taken as the robot's base frame "
                         "(no --base-frame)")
        return RawTrack(t=t, pose=pose, where=np.asarray(s.where, dtype=np.int64))
    for frame in dict.fromkeys(frames.tolist()):
        if frame == base:
            continue
        if tree is None:
            raise RecordingError(f"{bag}:{topic}: poses in frame {frame!r}, not the base frame {base!r}, and the bag "
                                 "has no /tf or /tf_static to chain them with")
        sel = frames == frame
        what = f"the frame of {topic}" + (" (an empty header.frame_id)" if not frame else "")
        pose[sel] = compose(tree.poses(tree.chain(frame, base, what), t[sel]), pose[sel])
    return RawTrack(t=t, pose=pose, where=np.asarray(s.where, dtype=np.int64))


def _check_landmarks(bag: Path, frames: Sequence[str], base: str | None, topics: Mapping[str, str]) -> None:
    names = [*frames, *topics]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise RecordingError(f"{bag}: landmark name(s) {twice} given twice (--landmark-frames, --landmark-topics)")
    if frames and base is None:
        raise RecordingError(f"{bag}: landmark frames {list(frames)} need the robot's base frame (--base-frame)")
    if base is not None and base in frames:
        raise RecordingError(f"{bag}: landmark frame {base!r} is the base frame itself")
    if not all(isinstance(n, str) and n for n in names):
        raise RecordingError(f"{bag}: landmark names must be non-empty, got {names}")


def read_bag(path: str | Path, joint_names: Sequence[str], joint_topic: str | None,
             landmark_frames: Sequence[str] = (), base_frame: str | None = None,
             landmark_topics: Mapping[str, str] | None = None, notes: list[str] | None = None) -> RawRecording:
    """One bag as a ``RawRecording`` (module docstring): joints ``(S, len(joint_names))`` from the
    ``JointState`` topic ``joint_topic`` (None: the bag's only one), a track per landmark frame
    (chained to ``base_frame`` through tf) then per ``{name: PoseStamped topic}`` of
    ``landmark_topics``, in that order. ``notes``: where to append what the reading assumed (a
    stream timed by receive times). ``RecordingError`` on a bag that cannot be used."""
    bag = Path(path)
    notes = [] if notes is None else notes
    frames = [_frame_id(f) for f in landmark_frames]
    base = _frame_id(base_frame) if base_frame is not None else None
    pose_topics = dict(landmark_topics or {})
    _check_landmarks(bag, frames, base, pose_topics)
    joints = _JointRows(joint_names)
    with _open(bag) as reader:
        types = {name: info.msgtype for name, info in reader.topics.items()}
        topic = _joint_topic(bag, types, joint_topic)
        for name, pose_topic in pose_topics.items():
            _check_topic(bag, types, pose_topic, (POSE_STAMPED,), f"landmark {name!r}")
        tf_topics = [t for t in TF_TOPICS if t in types] if (frames or (pose_topics and base)) else []
        if frames and not tf_topics:
            raise RecordingError(f"{bag}: landmark frames {frames} need /tf or /tf_static, which the bag lacks "
                                 f"(its topics: {_topic_list(types)})")
        for t in tf_topics:
            _check_topic(bag, types, t, TF_TYPES, "tf")
        streams = _read_streams(reader, bag, topic, list(pose_topics.values()), tf_topics, joints)
    source = f"{bag.name}:{topic}"
    js = streams[topic]
    if not js.data:
        raise RecordingError(f"{bag}:{topic}: no JointState message names any of the robot's joints "
                             f"{list(joint_names)} (the names seen: {list(joints.seen) or 'none, no messages'})")
    q = np.array(js.data, dtype=float)
    never = [j for k, j in enumerate(joints.joint_names) if np.isnan(q[:, k]).all()]
    if never:
        raise RecordingError(f"{bag}:{topic}: no message gives the robot's joint(s) {never} (the names seen: "
                             f"{list(joints.seen)})")
    tree = TfTree(bag, {t: (streams[t].times(f"{bag.name}:{t}", notes), streams[t].where, streams[t].data)
                        for t in tf_topics}) if tf_topics else None
    tracks = {}
    for f in frames:  # (_check_landmarks: a base frame; tf topics were checked above)
        assert tree is not None and base is not None
        tracks[f] = tree.track(tree.chain(f, base, "landmark frame"))
    for name, pose_topic in pose_topics.items():
        tracks[name] = _pose_track(bag, pose_topic, streams[pose_topic], base, tree, notes)
    empty = [n for n, tr in tracks.items() if not len(tr.t)]
    if empty:
        raise RecordingError(f"{bag}: no reading of landmark(s) {empty} (a topic without messages, or tf frames "
                             "whose moving transforms never overlap in time)")
    used = [*(tf_topics if frames else []), *pose_topics.values()]
    return RawRecording(name=_bag_name(bag), t=js.times(source, notes), q=q, tracks=tracks, joint_source=source,
                        landmark_source=f"{bag.name}:{','.join(dict.fromkeys(used))}" if used else "",
                        joint_where=np.asarray(js.where, dtype=np.int64), unit="message")


# ---------------------------------------------------------------------------------------------
# split_on_pause


def _still_until(q: np.ndarray, i: int, tolerance: float) -> int:
    """The last index ``j >= i`` such that every row ``q[i..j]`` is within ``tolerance`` of ``q[i]``."""
    j, step = i, 64
    while j + 1 < len(q):
        block = q[j + 1: j + 1 + step]
        out = np.flatnonzero(np.abs(block - q[i]).max(axis=1) > tolerance)
        if len(out):
            return j + int(out[0])
        j, step = j + len(block), step * 2
    return len(q) - 1


def _pauses(t: np.ndarray, q: np.ndarray, min_pause_s: float, tolerance: float) -> list[tuple[int, int]]:
    """``(first, last)`` rows of each pause: readings over at least ``min_pause_s`` during which every
    joint stays within ``tolerance`` of where the pause starts (rows with NaN skipped)."""
    ok = np.flatnonzero(np.isfinite(q).all(axis=1))
    tv, qv = t[ok], q[ok]
    out, i = [], 0
    while i < len(ok):
        j = _still_until(qv, i, tolerance)
        if tv[j] - tv[i] >= min_pause_s:
            out.append((int(ok[i]), int(ok[j])))
            i = j + 1
        else:
            i += 1
    return out


def _track_part(track: RawTrack, t0: float, t1: float) -> RawTrack:
    """The readings within ``[t0, t1]`` and the one on each side of it (a landmark read once is in
    every part)."""
    inside = (track.t >= t0) & (track.t <= t1)
    before, after = np.flatnonzero(track.t < t0), np.flatnonzero(track.t > t1)
    if len(before):
        inside[before[np.argmax(track.t[before])]] = True
    if len(after):
        inside[after[np.argmin(track.t[after])]] = True
    return RawTrack(t=track.t[inside], pose=track.pose[inside], where=track.where[inside])


def split_on_pause(raw: RawRecording, min_pause_s: float, tolerance_rad: float = PAUSE_TOLERANCE) \
        -> list[RawRecording]:
    """``raw`` cut in the middle of every pause between two motions: where every joint stays within
    ``tolerance_rad`` of where the pause starts for at least ``min_pause_s`` (the pauses at the
    start and the end are no cuts). The pieces are named ``<name>_01``, ``<name>_02``, ...; each
    keeps its landmark readings (and the one before and after). ``RecordingError`` when nothing
    is cut."""
    if not (math.isfinite(min_pause_s) and min_pause_s > 0 and math.isfinite(tolerance_rad) and tolerance_rad >= 0):
        raise RecordingError(f"split on pause: the pause must be a positive number of seconds and the tolerance "
                             f"at least 0 rad, got {min_pause_s!r} s, {tolerance_rad!r} rad")
    ok = np.flatnonzero(np.isfinite(raw.q).all(axis=1))
    inner = [(a, b) for a, b in _pauses(raw.t, raw.q, min_pause_s, tolerance_rad) if len(ok) and ok[0] < a
             and b < ok[-1]]
    if not inner:
        raise RecordingError(f"{raw.joint_source or raw.name}: no pause of at least {min_pause_s:g} s with every "
                             f"joint within {tolerance_rad:g} rad between two motions, so nothing to split: "
                             "shorten --split-on-pause or raise --pause-tolerance")
    cuts = [a + int(np.argmin(np.abs(raw.t[a: b + 1] - 0.5 * (raw.t[a] + raw.t[b])))) for a, b in inner]
    bounds = [0, *cuts, len(raw.t)]
    pieces = []
    for k, (a, b) in enumerate(itertools.pairwise(bounds)):
        t0, t1 = raw.t[a], raw.t[b - 1]
        pieces.append(RawRecording(name=f"{raw.name}_{k + 1:02d}", t=raw.t[a:b], q=raw.q[a:b],
                                   tracks={n: _track_part(tr, t0, t1) for n, tr in raw.tracks.items()},
                                   joint_source=raw.joint_source, landmark_source=raw.landmark_source,
                                   joint_where=raw.joint_where[a:b], unit=raw.unit))  # type: ignore[index]
    return pieces


# ---------------------------------------------------------------------------------------------
# the command line


def _names(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(","))
    if not all(names):
        raise argparse.ArgumentTypeError(f"expected FRAME,FRAME,... (names separated by commas), got {text!r}")
    return names


def _topic_map(text: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for item in text.split(","):
        name, eq, topic = item.partition("=")
        if not (eq and name.strip() and topic.strip()) or name.strip() in out:
            raise argparse.ArgumentTypeError(f"expected NAME=TOPIC,NAME=TOPIC,... with distinct names, got {text!r}")
        out[name.strip()] = topic.strip()
    return out


def add_bag_arguments(parser: argparse.ArgumentParser) -> None:
    """The options for bag input, in a group of their own: ``--joint-topic``, ``--landmark-frames``,
    ``--base-frame``, ``--landmark-topics``, ``--split-on-pause``, ``--pause-tolerance``."""
    g = parser.add_argument_group("ROS bags (RECORDINGS a .bag, a .mcap, a ROS 2 bag folder or a folder of those, "
                                  'one per demonstration; needs pip install ".[ros]")')
    g.add_argument("--joint-topic", default=None, metavar="TOPIC",
                   help="the arm's sensor_msgs/JointState topic (default: the bag's only one)")
    g.add_argument("--landmark-frames", type=_names, default=(), metavar="FRAME,...",
                   help="tf frames read as landmarks, chained to --base-frame through /tf and /tf_static")
    g.add_argument("--base-frame", default=None, metavar="FRAME", help="the robot's base frame in tf")
    g.add_argument("--landmark-topics", type=_topic_map, default={}, metavar="NAME=TOPIC,...",
                   help="geometry_msgs/PoseStamped topics read as the landmarks NAME (chained to --base-frame "
                        "through tf when in another frame)")
    g.add_argument("--split-on-pause", type=float, default=None, metavar="SECONDS",
                   help="cut each bag into demonstrations where the arm holds still this long (default: a bag is "
                        "one demonstration)")
    g.add_argument("--pause-tolerance", type=float, default=PAUSE_TOLERANCE, metavar="RAD",
                   help="how far a joint may move during a pause of --split-on-pause")


def bag_options_given(args: argparse.Namespace) -> list[str]:
    """The bag options set on the command line (to refuse them when the input is CSV)."""
    defaults: dict[str, object] = {"landmark_frames": (), "landmark_topics": {}, "pause_tolerance": PAUSE_TOLERANCE}
    return [opt for dest, opt in BAG_OPTIONS.items() if getattr(args, dest, None) not in (None, defaults.get(dest))]


def raws_from_args(path: str | Path, args: argparse.Namespace, robot, notes: list[str] | None = None) \
        -> list[RawRecording]:
    """Every bag of ``path`` (``find_bags``) read with the options of ``add_bag_arguments`` for
    ``robot`` (a ``RobotSpec``), cut by ``--split-on-pause`` when given. ``notes``: where to append
    what the reading assumed. ``RecordingError`` on bad input."""
    from lfd.cli import UsageError

    csv_only = [opt for dest, opt in (("columns", "--columns"), ("frame_pose", "--frame-pose"))
                if getattr(args, dest, None) is not None]
    if csv_only:
        raise UsageError(f"{' and '.join(csv_only)}: for CSV recordings; a bag names its joints in its JointState "
                         "messages and its landmark frames in tf (--base-frame)")
    if args.split_on_pause is not None and not (math.isfinite(args.split_on_pause) and args.split_on_pause > 0):
        raise UsageError(f"--split-on-pause must be a positive number of seconds, got {args.split_on_pause}")
    if not (math.isfinite(args.pause_tolerance) and args.pause_tolerance >= 0):
        raise UsageError(f"--pause-tolerance must be at least 0 rad, got {args.pause_tolerance}")
    if not args.landmark_frames and not args.landmark_topics:
        raise UsageError("a bag needs its landmarks: --landmark-frames with --base-frame, or --landmark-topics")
    raws = []
    for bag in find_bags(path):
        raw = read_bag(bag, robot.joint_names, args.joint_topic, args.landmark_frames, args.base_frame,
                       args.landmark_topics, notes=notes)
        raws.extend(split_on_pause(raw, args.split_on_pause, args.pause_tolerance)
                    if args.split_on_pause is not None else [raw])
    return raws
