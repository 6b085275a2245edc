"""ROS bags read by ``lfd.io.rosbag``: small bags written with rosbags' own writers (ROS 1, ROS 2 with
sqlite3 and mcap storage, a bare .mcap) holding Baxter joint states (the left arm's joints shuffled
among the other arm's and the grippers'), a tf tree ``world -> base -> camera -> hand`` with
``world -> table`` beside it (static and moving transforms) and a PoseStamped topic in the camera
frame. The readings are compared with the poses composed in numpy, bags with the equivalent CSVs
through the same import, and every refusal names the bag and the topic or frame."""

from __future__ import annotations

import argparse
import shutil
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import rosbags  # noqa: F401,E402  (the [ros] extra, which make installs: its absence is a failure, not a skip)

from lfd.io.raw import RecordingError
from lfd.io.rosbag import (
    add_bag_arguments,
    bag_options_given,
    find_bags,
    is_bag_input,
    raws_from_args,
    read_bag,
    split_on_pause,
)
from lfd.robot.robots import BAXTER_LEFT

JOINTS = BAXTER_LEFT.joint_names
OTHERS = ("left_gripper", "right_s0", "right_s1", "right_e0", "right_e1", "right_w0", "right_w1", "right_w2",
          "right_gripper", "head_pan")
JOINT_TOPIC = "/robot/joint_states"
KINDS = ("ros1", "sqlite3", "mcap")
T0_NS = 1_000_000_000_000  # the recordings start 1000 s into the sensors' clock


def _T(p7) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = Rotation.from_quat(p7[3:]).as_matrix(), p7[:3]
    return T


def _p7(T) -> np.ndarray:
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_quat()])


def _sec(ns: int) -> float:
    """A stamp in seconds as the reader computes it from (sec, nanosec)."""
    return ns // 10**9 + (ns % 10**9) * 1e-9


@dataclass
class Rec:
    """What a bag holds: joint messages ``(stamp ns, names, positions)``, the hand's ``T_camera_hand``
    and the bowl's ``T_camera_bowl`` readings ``(stamp ns, (4, 4))``, the static transforms."""

    joints: list
    hand: list
    bowl: list
    static_ns: int
    T_world_base: np.ndarray
    T_world_table: np.ndarray
    T_base_camera: np.ndarray


def _rec(q: np.ndarray, landmarks: np.ndarray, seed: int, dt: float = 0.1, pause: float = 1.0) -> Rec:
    """A recording of a demonstration ``q (S, 7)`` with ``landmarks (S, 3, 4, 4)`` (hand tracked; the
    bowl and the table from the first sample): joints at ~50 Hz with jitter and pauses of ``pause``
    s at both ends, the hand at 30 Hz (turning as it moves), the bowl at 10 Hz."""
    rng = np.random.default_rng(seed)
    t_demo = np.arange(len(q)) * dt
    end = t_demo[-1] + 2 * pause
    t = np.sort(np.arange(0.0, end, 0.02) + rng.uniform(-0.004, 0.004, int(np.ceil(end / 0.02))))
    t = t[t >= 0]
    tc = np.clip(t - pause, 0.0, t_demo[-1])
    qs = np.stack([np.interp(tc, t_demo, q[:, j]) for j in range(7)], axis=1)
    joints = []
    for k in range(len(t)):
        names = [*JOINTS, *OTHERS]
        pos = dict(zip(names, [*qs[k], *rng.uniform(-0.5, 0.5, len(OTHERS))]))
        rng.shuffle(names)
        joints.append((T0_NS + int(round(t[k] * 1e9)), names, [pos[n] for n in names]))
    T_base_camera = _T([0.1, 0.0, 0.6, *Rotation.from_euler("xyz", [0.2, 0.9, -0.3]).as_quat()])
    T_world_base = _T([0.5, -0.2, 0.8, *Rotation.from_euler("z", 0.7).as_quat()])
    th = np.arange(0.0, end + 0.02, 1 / 30)
    thc = np.clip(th - pause, 0.0, t_demo[-1])
    hand = []
    for k in range(len(th)):
        T_base_hand = np.eye(4)
        T_base_hand[:3, 3] = [np.interp(thc[k], t_demo, landmarks[:, 0, i, 3]) for i in range(3)]
        T_base_hand[:3, :3] = Rotation.from_euler("zy", [0.6 * th[k], 0.3]).as_matrix() @ landmarks[0, 0, :3, :3]
        hand.append((T0_NS + int(round(th[k] * 1e9)), np.linalg.inv(T_base_camera) @ T_base_hand))
    bowl = [(T0_NS + int(round(tb * 1e9)) + 7_000_000, np.linalg.inv(T_base_camera) @ landmarks[0, 1])
            for tb in np.arange(0.0, end, 0.1)]
    return Rec(joints, hand, bowl, T0_NS - 500_000_000, T_world_base, T_world_base @ landmarks[0, 2], T_base_camera)


@pytest.fixture(scope="module")
def demos():
    from lfd.learning.synthetic import make_synthetic
    from lfd.robot.kinematics import KinematicModel

    ds, _ = make_synthetic(KinematicModel.from_spec(), n_demos=2, time_steps=8, Z=3, seed=0, landmark_motion=0.4,
                           samples_per_step=(5, 8))
    return ds


@pytest.fixture(scope="module")
def recs(demos):
    return [_rec(d.q, d.landmarks, seed=i) for i, d in enumerate(demos.demos)]


# ---------------------------------------------------------------------------------------------
# writing bags with rosbags' own writers


def _typestore(kind: str):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    if kind == "ros1":  # Noetic's store lacks tf2_msgs; a ROS 1 bag carries its definition
        ts = get_typestore(Stores.ROS1_NOETIC)
        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
        return ts
    return get_typestore(Stores.ROS2_HUMBLE)


class _Msgs:
    """Messages of one typestore."""

    def __init__(self, kind: str, zero_stamps: bool = False):
        self.kind, self.ts, self.zero = kind, _typestore(kind), zero_stamps
        self.T = self.ts.types

    def header(self, ns: int, frame: str, zero: bool = False):
        ns = 0 if zero else ns
        kw = {"seq": 0} if self.kind == "ros1" else {}
        stamp = self.T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        return self.T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **kw)

    def joint_state(self, ns: int, names, positions):
        empty = np.array([], dtype=float)
        return self.T["sensor_msgs/msg/JointState"](header=self.header(ns, "", self.zero), name=list(names),
                                                     position=np.asarray(positions, dtype=float), velocity=empty,
                                                     effort=empty)

    def tf(self, transforms):
        """``transforms``: ``(stamp ns, parent, child, (4, 4))``."""
        T = self.T
        out = []
        for ns, parent, child, M in transforms:
            p7 = _p7(M)
            tr = T["geometry_msgs/msg/Transform"](translation=T["geometry_msgs/msg/Vector3"](x=p7[0], y=p7[1], z=p7[2]),
                                                  rotation=T["geometry_msgs/msg/Quaternion"](x=p7[3], y=p7[4], z=p7[5],
                                                                                              w=p7[6]))
            out.append(T["geometry_msgs/msg/TransformStamped"](header=self.header(ns, parent),
                                                               child_frame_id=child, transform=tr))
        return T["tf2_msgs/msg/TFMessage"](transforms=out)

    def pose(self, ns: int, frame: str, M):
        T, p7 = self.T, _p7(M)
        pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=p7[0], y=p7[1], z=p7[2]),
                                           orientation=T["geometry_msgs/msg/Quaternion"](x=p7[3], y=p7[4], z=p7[5],
                                                                                          w=p7[6]))
        return T["geometry_msgs/msg/PoseStamped"](header=self.header(ns, frame, self.zero), pose=pose)

    def serialize(self, msg):
        fn = self.ts.serialize_ros1 if self.kind == "ros1" else self.ts.serialize_cdr
        return fn(msg, msg.__msgtype__)


def _messages(m: _Msgs, rec: Rec, joint_topic: str = JOINT_TOPIC, bowl_frame: str = "camera", extra_tf=()):
    """``(receive ns, topic, message)`` of a recording; receive times 3 ms after the stamps."""
    out = [(rec.static_ns + 1, "/tf_static", m.tf([(rec.static_ns, "world", "base", rec.T_world_base),
                                                   (rec.static_ns, "world", "table", rec.T_world_table),
                                                   (rec.static_ns, "base", "camera", rec.T_base_camera),
                                                   *extra_tf]))]
    out += [(ns + 3_000_000, joint_topic, m.joint_state(ns, names, pos)) for ns, names, pos in rec.joints]
    out += [(ns + 3_000_000, "/tf", m.tf([(ns, "camera", "hand", M)])) for ns, M in rec.hand]
    out += [(ns + 3_000_000, "/bowl_pose", m.pose(ns, bowl_frame, M)) for ns, M in rec.bowl]
    return sorted(out, key=lambda x: x[0])


def _write(path: Path, kind: str, messages, m: _Msgs) -> Path:
    """A bag of ``kind`` (ros1, sqlite3, mcap) at ``path`` (``.bag`` added for ROS 1)."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    if kind == "ros1":
        path = path.with_suffix(".bag")
        writer = Writer1(path)
    else:
        plugin = StoragePlugin.SQLITE3 if kind == "sqlite3" else StoragePlugin.MCAP
        writer = Writer2(path, version=9, storage_plugin=plugin)
    types = {topic: msg.__msgtype__ for _, topic, msg in messages}
    with writer as w:
        conns = {topic: w.add_connection(topic, msgtype, typestore=m.ts) for topic, msgtype in types.items()}
        for ns, topic, msg in messages:
            w.write(conns[topic], ns, m.serialize(msg))
    return path


def _bag(tmp_path: Path, kind: str, rec: Rec, name: str = "demo", zero_stamps=False, **kw) -> Path:
    m = _Msgs(kind, zero_stamps)
    return _write(tmp_path / name, kind, _messages(m, rec, **kw), m)


def _read(bag, **kw):
    args = {"joint_topic": JOINT_TOPIC, "landmark_frames": ("hand", "table"), "base_frame": "base",
            "landmark_topics": {"bowl": "/bowl_pose"}, **kw}
    return read_bag(bag, JOINTS, **args)


def _expected(rec: Rec) -> dict:
    """``{landmark: (times (K,), T_base_landmark (K, 4, 4))}`` composed in numpy."""
    hand = (np.array([_sec(ns) for ns, _ in rec.hand]), np.stack([rec.T_base_camera @ M for _, M in rec.hand]))
    table = (np.array([_sec(rec.static_ns)]), (np.linalg.inv(rec.T_world_base) @ rec.T_world_table)[None])
    bowl = (np.array([_sec(ns) for ns, _ in rec.bowl]), np.stack([rec.T_base_camera @ M for _, M in rec.bowl]))
    return {"hand": hand, "table": table, "bowl": bowl}


def _joint_rows(rec: Rec) -> tuple[np.ndarray, np.ndarray]:
    t = np.array([_sec(ns) for ns, _, _ in rec.joints])
    q = np.array([[dict(zip(names, pos))[j] for j in JOINTS] for _, names, pos in rec.joints])
    return t, q


def _assert_poses(track, t, T):
    assert np.array_equal(track.t, t)
    got = np.stack([_T(p) for p in track.pose])
    np.testing.assert_allclose(got, T, atol=1e-9, rtol=0)
    np.testing.assert_allclose(np.linalg.norm(track.pose[:, 3:], axis=1), 1.0, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# reading


@pytest.mark.parametrize("kind", KINDS)
def test_a_bag_reads_the_joints_and_the_chained_poses(tmp_path, recs, kind):
    rec = recs[0]
    raw = _read(_bag(tmp_path, kind, rec))
    t, q = _joint_rows(rec)
    assert raw.name == "demo" and raw.unit == "message"
    assert np.array_equal(raw.t, t) and np.array_equal(raw.q, q)  # the left arm's, from shuffled names
    assert np.array_equal(raw.joint_where, np.arange(1, len(t) + 1))
    bag_name = "demo.bag" if kind == "ros1" else "demo"
    assert raw.joint_source == f"{bag_name}:{JOINT_TOPIC}"
    assert list(raw.tracks) == ["hand", "table", "bowl"]
    for name, (tt, T) in _expected(rec).items():
        _assert_poses(raw.tracks[name], tt, T)
    assert np.array_equal(raw.tracks["hand"].where, np.arange(1, len(rec.hand) + 1))  # message numbers on /tf
    assert raw.tracks["table"].where.tolist() == [1]  # read once, from /tf_static's one message


def test_a_bare_mcap_file_reads_as_its_bag_folder(tmp_path, recs):
    folder = _bag(tmp_path, "mcap", recs[0])
    lone = shutil.copy(next(folder.glob("*.mcap")), tmp_path / "lone.mcap")
    a, b = _read(folder), _read(lone)
    assert b.name == "lone" and b.joint_source == f"lone.mcap:{JOINT_TOPIC}"
    assert np.array_equal(a.q, b.q) and np.array_equal(a.t, b.t)
    assert all(np.array_equal(a.tracks[n].pose, b.tracks[n].pose) for n in a.tracks)


def test_a_moving_chain_is_interpolated_at_each_transforms_stamp(tmp_path, recs):
    """camera -> hand at 30 Hz and base -> camera moving at 10 Hz, stamped 5 ms apart: a reading at
    every stamp of either, the other transform interpolated there (positions linearly, slerp)."""
    rec = recs[0]
    m = _Msgs("sqlite3")
    msgs = [x for x in _messages(m, rec) if x[1] != "/tf_static"]
    msgs.append((rec.static_ns, "/tf_static", m.tf([(rec.static_ns, "world", "base", rec.T_world_base)])))
    cam = [(T0_NS + 5_000_000 + int(k * 1e8), rec.T_base_camera @ _T([0.01 * k, 0, 0.002 * k,
                                                                     *Rotation.from_euler("x", 0.05 * k).as_quat()]))
           for k in range(int(len(rec.hand) / 3) + 2)]
    msgs += [(ns + 1, "/tf", m.tf([(ns, "base", "camera", M)])) for ns, M in cam]
    raw = read_bag(_write(tmp_path / "moving", "sqlite3", sorted(msgs, key=lambda x: x[0]), m), JOINTS, JOINT_TOPIC,
                   ["hand"], "base")
    tc, Tc = np.array([_sec(ns) for ns, _ in cam]), np.stack([M for _, M in cam])
    th, Th = np.array([_sec(ns) for ns, _ in rec.hand]), np.stack([M for _, M in rec.hand])
    t = np.union1d(tc, th)
    t = t[(t >= max(tc[0], th[0])) & (t <= min(tc[-1], th[-1]))]

    def at(ts, Ts, x):  # scipy's interpolation of one transform
        from scipy.spatial.transform import Slerp
        out = np.tile(np.eye(4), (len(x), 1, 1))
        out[:, :3, 3] = np.stack([np.interp(x, ts, Ts[:, i, 3]) for i in range(3)], axis=1)
        out[:, :3, :3] = Slerp(ts, Rotation.from_matrix(Ts[:, :3, :3]))(x).as_matrix()
        return out

    _assert_poses(raw.tracks["hand"], t, at(tc, Tc, t) @ at(th, Th, t))
    assert len(t) > len(th) - 5  # both transforms' stamps give readings


def test_a_dropout_is_a_nan_row_and_messages_of_other_joints_are_skipped(tmp_path, recs):
    rec = recs[0]
    joints = list(rec.joints)
    ns, names, pos = joints[10]
    joints[10] = (ns, [n for n in names if n != "left_e1"], [p for n, p in zip(names, pos) if n != "left_e1"])
    joints.insert(20, (joints[20][0] - 1000, ["left_gripper"], [0.5]))  # a gripper's message
    raw = _read(_bag(tmp_path, "ros1", replace(rec, joints=joints)))
    assert len(raw.t) == len(rec.joints)
    assert 21 not in raw.joint_where.tolist() and raw.joint_where[20] == 22  # message 21 skipped, numbers kept
    e1 = JOINTS.index("left_e1")  # the row keeps the joints it has; the missing one is NaN
    assert np.isnan(raw.q[10, e1]) and np.isnan(raw.q).sum() == 1
    assert np.array_equal(np.delete(raw.q[10], e1), np.delete(_joint_rows(rec)[1][10], e1))


def test_unset_stamps_use_the_receive_times_with_a_note(tmp_path, recs):
    rec = recs[0]
    notes: list[str] = []
    raw = read_bag(_bag(tmp_path, "mcap", rec, zero_stamps=True), JOINTS, JOINT_TOPIC,
                   landmark_topics={"bowl": "/bowl_pose"}, base_frame="base", notes=notes)
    assert np.allclose(raw.t, [_sec(ns) + 0.003 for ns, _, _ in rec.joints], atol=1e-9)
    assert np.allclose(raw.tracks["bowl"].t, [_sec(ns) + 0.003 for ns, _ in rec.bowl], atol=1e-9)
    assert any(f"demo:{JOINT_TOPIC}: every header stamp is zero" in n and "receive times" in n for n in notes)
    assert any("demo:/bowl_pose: every header stamp is zero" in n for n in notes)


def test_find_bags(tmp_path, recs):
    folder = tmp_path / "bags"
    folder.mkdir()
    b = _bag(folder, "ros1", recs[0], name="b_demo")
    a = _bag(folder, "sqlite3", recs[1], name="a_demo")
    (folder / ".hidden").write_text("x")
    assert find_bags(folder) == [a, b] and find_bags(b) == [b] and find_bags(a) == [a]
    assert is_bag_input(folder) and is_bag_input(a) and is_bag_input(b)
    assert not is_bag_input(Path(__file__).parent / "data" / "recordings")
    (folder / "notes.txt").write_text("x")
    with pytest.raises(RecordingError, match=r"notes\.txt: not a ROS bag"):
        find_bags(folder)
    (folder / "notes.txt").unlink()
    shutil.copytree(a, folder / "B_DEMO")
    with pytest.raises(RecordingError, match="two bags named"):
        find_bags(folder)


# ---------------------------------------------------------------------------------------------
# split_on_pause


def test_split_on_pause_cuts_three_motions(tmp_path, demos):
    """Three motions (a synthetic demonstration's first half, its second half, all of it backwards)
    at 50 Hz with encoder noise, 2 s still before, between and after them."""
    q = demos.demos[0].q
    h = len(q) // 2
    legs = [q[:h], q[h - 1:], q[::-1]]
    rows, motions = [q[0]] * 100, []
    for leg in legs:
        motions.append((len(rows), len(rows) + 5 * len(leg)))
        rows += [*np.repeat(leg, 5, axis=0), *[leg[-1]] * 100]
    rng = np.random.default_rng(3)
    joints = [(T0_NS + k * 20_000_000, list(JOINTS), list(r + rng.normal(0, 0.002, 7))) for k, r in enumerate(rows)]
    bowl = [(T0_NS + k * 100_000_000, np.eye(4)) for k in range(len(rows) // 5)]
    rec = Rec(joints, [], bowl, T0_NS, np.eye(4), np.eye(4), np.eye(4))
    raw = read_bag(_bag(tmp_path, "ros1", rec, name="session", bowl_frame="base"), JOINTS, JOINT_TOPIC,
                   landmark_topics={"bowl": "/bowl_pose"}, base_frame="base")
    pieces = split_on_pause(raw, 1.5, 0.02)
    assert [p.name for p in pieces] == ["session_01", "session_02", "session_03"]
    assert np.array_equal(np.concatenate([p.t for p in pieces]), raw.t)
    cuts = [p.t[0] for p in pieces[1:]]
    for k, (a, b) in enumerate(motions):  # each piece holds one motion and about 1 s still around it
        p = pieces[k]
        assert p.t[0] <= raw.t[a] - 0.9 and p.t[-1] >= raw.t[b - 1] + 0.9
        np.testing.assert_allclose(p.q[0], legs[k][0], atol=0.01)
        np.testing.assert_allclose(p.q[-1], legs[k][-1], atol=0.01)
        assert np.array_equal(p.joint_where, raw.joint_where[np.searchsorted(raw.t, p.t)])
        bowl_t = p.tracks["bowl"].t  # the landmark's readings span the piece, and one beyond each end
        assert bowl_t[0] <= p.t[0] and (bowl_t[-1] >= p.t[-1] or k == 2) and len(bowl_t) >= (p.t[-1] - p.t[0]) * 10
    assert all(abs(c - raw.t[b] - 1.0) < 0.05 for c, (_, b) in zip(cuts, motions))  # mid-pause
    with pytest.raises(RecordingError, match=r"session\.bag:/robot/joint_states: no pause of at least 5 s"):
        split_on_pause(raw, 5.0, 0.02)


# ---------------------------------------------------------------------------------------------
# refusals


def test_refusals_name_the_bag_and_the_topic_or_frame(tmp_path, recs):
    rec = recs[0]
    bag = _bag(tmp_path, "ros1", rec, extra_tf=[(rec.static_ns, "odom", "cart", np.eye(4))])
    with pytest.raises(RecordingError, match=r"demo\.bag: joint topic '/joint_states' is not in the bag \(its "
                                             r"topics: /bowl_pose .*/robot/joint_states \(sensor_msgs/msg/JointSt"):
        _read(bag, joint_topic="/joint_states")
    with pytest.raises(RecordingError, match=r"demo\.bag:/tf: messages of type tf2_msgs/msg/TFMessage, not "
                                             r"sensor_msgs/msg/JointState"):
        _read(bag, joint_topic="/tf")
    with pytest.raises(RecordingError, match=r"demo\.bag: landmark frame 'cart' is not connected to the base frame "
                                             r"'base' .*\[cart, odom\]"):
        _read(bag, landmark_frames=("hand", "cart"))
    with pytest.raises(RecordingError, match=r"demo\.bag: landmark frame 'mars' is not connected"):
        _read(bag, landmark_frames=("mars",))
    with pytest.raises(RecordingError, match=r"demo\.bag: the base frame 'pedestal' is not in /tf or /tf_static"):
        _read(bag, base_frame="pedestal")
    with pytest.raises(RecordingError, match=r"demo\.bag: landmark 'bowl' topic '/bowl' is not in the bag"):
        _read(bag, landmark_topics={"bowl": "/bowl"})
    # a robot joint never published
    joints = [(ns, [n for n in names if n != "left_w2"], [p for n, p in zip(names, pos) if n != "left_w2"])
              for ns, names, pos in rec.joints]
    bag = _bag(tmp_path, "sqlite3", replace(rec, joints=joints), name="nowrist")
    with pytest.raises(RecordingError, match=r"nowrist:/robot/joint_states: no message gives the robot's joint\(s\) "
                                             r"\['left_w2'\] \(the names seen: .*'right_w2'"):
        _read(bag)
    # a pose in a frame tf does not connect
    bag = _bag(tmp_path, "mcap", rec, name="lostbowl", bowl_frame="kinect")
    with pytest.raises(RecordingError, match=r"lostbowl: the frame of /bowl_pose 'kinect' is not connected to the "
                                             r"base frame 'base'"):
        _read(bag)


def test_a_damaged_bag_and_a_missing_rosbags_are_refused(tmp_path, recs, monkeypatch):
    bag = _bag(tmp_path, "ros1", recs[0])
    cut = tmp_path / "cut.bag"
    cut.write_bytes(bag.read_bytes()[: bag.stat().st_size // 2])
    with pytest.raises(RecordingError, match=r"cut\.bag: cannot be read as a ROS bag \(AnyReaderError: "):
        _read(cut)
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file" * 8)
    with pytest.raises(RecordingError, match=r"junk\.mcap: cannot be read as a ROS bag"):
        _read(junk)
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)
    with pytest.raises(RecordingError, match=r'demo\.bag: reading ROS bags needs the rosbags package .*pip install '
                                             r'"\.\[ros\]"'):
        _read(bag)


def test_the_command_line_options(tmp_path, recs):
    p = argparse.ArgumentParser()
    add_bag_arguments(p)
    args = p.parse_args(["--joint-topic", JOINT_TOPIC, "--landmark-frames", "hand,table", "--base-frame", "base",
                         "--landmark-topics", "bowl=/bowl_pose"])
    assert args.landmark_frames == ("hand", "table") and args.landmark_topics == {"bowl": "/bowl_pose"}
    assert bag_options_given(args) == ["--joint-topic", "--landmark-frames", "--base-frame", "--landmark-topics"]
    assert bag_options_given(p.parse_args([])) == []
    folder = tmp_path / "bags"
    folder.mkdir()
    for i, rec in enumerate(recs):
        _bag(folder, KINDS[i], rec, name=f"demo_{i + 1:02d}")
    raws = raws_from_args(folder, args, BAXTER_LEFT)
    assert [r.name for r in raws] == ["demo_01", "demo_02"] and all(list(r.tracks) == ["hand", "table", "bowl"]
                                                                      for r in raws)
    with pytest.raises(SystemExit):
        p.parse_args(["--landmark-topics", "bowl"])


# ---------------------------------------------------------------------------------------------
# through the import: a bag and the equivalent CSVs make the same set


def _write_csvs(folder: Path, rec: Rec) -> None:
    """The recording as docs/RECORDINGS.md's CSVs: ``joints.csv`` (time + the joints' URDF names, the
    other arm's columns too) and ``landmarks.csv`` (the chained poses in the base frame)."""
    folder.mkdir(parents=True)
    lines = ["time," + ",".join([*JOINTS, *OTHERS])]
    for ns, names, pos in rec.joints:
        value = dict(zip(names, pos))
        lines.append(",".join(repr(float(x)) for x in [_sec(ns), *(value[n] for n in [*JOINTS, *OTHERS])]))
    (folder / "joints.csv").write_text("\n".join(lines) + "\n")
    lines = ["time,name,x,y,z,qx,qy,qz,qw"]
    for name, (t, T) in _expected(rec).items():
        lines += [",".join([repr(float(tk)), name, *(repr(float(x)) for x in _p7(Tk))]) for tk, Tk in zip(t, T)]
    (folder / "landmarks.csv").write_text("\n".join(lines) + "\n")


def _assert_same_set(a, b):
    assert a.landmark_names == b.landmark_names and a.joint_names == b.joint_names and len(a.demos) == len(b.demos)
    for da, db in zip(a.demos, b.demos):
        assert da.dt == db.dt and da.q.shape == db.q.shape and da.landmarks.shape == db.landmarks.shape
        np.testing.assert_allclose(da.q, db.q, atol=1e-9, rtol=0)
        np.testing.assert_allclose(da.landmarks, db.landmarks, atol=1e-9, rtol=0)


@pytest.mark.parametrize("kind", KINDS)
def test_bags_and_the_equivalent_csvs_import_to_the_same_set(tmp_path, recs, kind):
    from lfd.io.recordings import ImportSettings, import_raw, import_recordings

    bags = tmp_path / "bags"
    bags.mkdir()
    for i, rec in enumerate(recs):
        _bag(bags, kind, rec, name=f"demo_{i + 1:02d}")
        _write_csvs(tmp_path / "csv" / f"demo_{i + 1:02d}", rec)
    csv_set, csv_report = import_recordings(tmp_path / "csv", BAXTER_LEFT, 10.0, trim=0.02)
    raws = [_read(b) for b in find_bags(bags)]
    bag_set, bag_report = import_raw(raws, BAXTER_LEFT, ImportSettings(rate=10.0, trim=0.02), str(bags))
    _assert_same_set(bag_set, csv_set)
    assert bag_set.landmark_names == ("hand", "table", "bowl") and [d.name for d in bag_set.demos] == [
        "demo_01", "demo_02"]
    assert all(d.landmarks.ndim == 4 for d in bag_set.demos)  # the hand tracked
    assert [r["trimmed_start_s"] for r in bag_report] == [r["trimmed_start_s"] for r in csv_report]
    assert all(0.9 < r["trimmed_start_s"] < 1.1 for r in bag_report)  # the 1 s pause before each motion


def test_a_split_session_imports_as_its_pieces(tmp_path, recs):
    """One bag holding both demonstrations: the first, the arm moved to the second's start in 1 s,
    2 s still, the second; the bowl (a PoseStamped topic) swapped during the pause. Cut by
    --split-on-pause, the second piece imports to the same demonstration as its own bag, and the
    first starts as the first's own bag."""
    from lfd.io.recordings import ImportSettings, import_raw

    a, b = recs
    qa, qb = _joint_rows(a)[1][-1], _joint_rows(b)[1][0]
    end_a = a.joints[-1][0]
    move = [(end_a + k * 20_000_000, list(JOINTS), list(qa + (qb - qa) * min(k / 50, 1.0))) for k in range(1, 151)]
    shift = move[-1][0] + 20_000_000 - b.joints[0][0]
    swap = end_a + 2_500_000_000  # the bowl moves while the arm holds still
    bowl = [*a.bowl, *((ns, (a if ns < swap else b).bowl[0][1])
                       for ns in range(a.bowl[-1][0] + 100_000_000, b.bowl[0][0] + shift, 100_000_000))]
    both = Rec([*a.joints, *move, *((ns + shift, n, p) for ns, n, p in b.joints)], [],
               [*bowl, *((ns + shift, M) for ns, M in b.bowl)], a.static_ns, a.T_world_base, a.T_world_table,
               a.T_base_camera)
    p = argparse.ArgumentParser()
    add_bag_arguments(p)
    args = p.parse_args(["--joint-topic", JOINT_TOPIC, "--landmark-topics", "bowl=/bowl_pose", "--base-frame", "base",
                         "--split-on-pause", "1.5"])
    raws = raws_from_args(_bag(tmp_path, "mcap", both, name="session"), args, BAXTER_LEFT)
    assert [r.name for r in raws] == ["session_01", "session_02"]
    settings = ImportSettings(rate=10.0, trim=0.02)
    ds, report = import_raw(raws, BAXTER_LEFT, settings, "session")
    alone = [read_bag(_bag(tmp_path, "mcap", rec, name=f"alone_{i}"), JOINTS, JOINT_TOPIC, (), "base",
                      {"bowl": "/bowl_pose"}) for i, rec in enumerate(recs)]
    ds_alone, report_alone = import_raw(alone, BAXTER_LEFT, settings, "alone")
    _assert_same_set(replace(ds, demos=ds.demos[1:]), replace(ds_alone, demos=ds_alone.demos[1:]))
    first, first_alone = ds.demos[0], ds_alone.demos[0]
    assert first.n_samples > first_alone.n_samples + 5  # and the move to the second's start
    np.testing.assert_allclose(first.q[:first_alone.n_samples - 1], first_alone.q[:-1], atol=1e-9, rtol=0)
    assert report[0]["trimmed_start_s"] == report_alone[0]["trimmed_start_s"] > 0.9  # the first's 1 s pause


def test_lfd_import_reads_a_folder_of_bags(tmp_path, recs, capsys):
    from helpers import run_cli

    from lfd.io.import_csv import main
    from lfd.learning.demos import load_demos

    bags = tmp_path / "bags"
    bags.mkdir()
    for i, rec in enumerate(recs):
        _bag(bags, KINDS[i], rec, name=f"demo_{i + 1:02d}")
    r = run_cli(main, "lfd-import", [str(bags), "--out", str(tmp_path / "set"), "--task", "handover", "--rate", "10",
                                     "--time-steps", "8", "--trim-pauses", "0.02", "--joint-topic", JOINT_TOPIC,
                                     "--landmark-frames", "hand,table", "--base-frame", "base", "--landmark-topics",
                                     "bowl=/bowl_pose", "--no-plot"], capsys)
    assert r.returncode == 0, r.stderr
    ds = load_demos(tmp_path / "set")
    assert ds.landmark_names == ("hand", "table", "bowl") and len(ds.demos) == 2
    for i, rec in enumerate(recs):
        _write_csvs(tmp_path / "csv" / f"demo_{i + 1:02d}", rec)
    r = run_cli(main, "lfd-import", [str(tmp_path / "csv"), "--out", str(tmp_path / "csv_set"), "--task", "handover",
                                     "--rate", "10", "--time-steps", "8", "--trim-pauses", "0.02", "--no-plot"], capsys)
    assert r.returncode == 0, r.stderr
    _assert_same_set(ds, load_demos(tmp_path / "csv_set"))
    r = run_cli(main, "lfd-import", [str(bags), "--out", str(tmp_path / "x"), "--task", "handover",
                                     "--joint-topic", "/joint_states", "--landmark-frames", "hand", "--base-frame",
                                     "base"], capsys)
    assert r.returncode == 2 and "demo_01.bag: joint topic '/joint_states' is not in the bag" in r.stderr
    assert not (tmp_path / "x").exists()
