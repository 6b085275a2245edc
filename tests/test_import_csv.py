"""``lfd-import``: recorded CSVs (joints at an irregular ~50 Hz with noise, jitter, dropped rows
and pauses; a tracked hand at 30 Hz; landmarks read once) into a demonstration set that learns
the hidden task; resampling checked against known signals; every bad recording refused with one
line, nothing written. The recordings are ``tests/data/recordings`` (``make_recordings.py``)."""

from __future__ import annotations

import csv
import json
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from helpers import run_cli
from lfd.io.import_csv import main
from lfd.io.recordings import JointColumns, import_recordings
from lfd.learning.demos import load_demos
from lfd.robot.robots import BAXTER_LEFT, resolve_urdf

DATA = Path(__file__).resolve().parent / "data" / "recordings"
TRUE_TOOL = np.array([0.03, -0.02, 0.15])  # tests/data/recordings/TRUTH.txt


def _import(capsys, src, out, *extra):
    return run_cli(main, "lfd-import", [str(src), "--out", str(out), "--task", "handover", "--rate", "10",
                                        "--time-steps", "8", *extra], capsys)


def test_the_shipped_recordings_import_trim_and_learn_the_hand(tmp_path, capsys):
    from lfd.learning.learn import FitConfig, fit
    from lfd.robot.kinematics import KinematicModel

    r = _import(capsys, DATA, tmp_path / "set", "--trim-pauses", "0.02")
    assert r.returncode == 0, r.stderr
    trimmed = [float(x) for x in re.findall(r"trimmed ([0-9.]+) s \+ ([0-9.]+) s", r.stdout) for x in x]
    assert len(trimmed) == 10 and all(0.9 < x < 1.1 for x in trimmed), r.stdout  # the 1 s pauses, each end
    assert r.stdout.count("landmarks tracked") == 5
    # each recording's file is named (later messages name the file, not the recording)
    assert re.findall(r"^(demo_\d+) -> (demo_\d+\.npz):", r.stdout, re.M) == [
        (f"demo_{i + 1:02d}", f"demo_{i:03d}.npz") for i in range(5)]
    ds = load_demos(tmp_path / "set")
    assert ds.task.name == "handover" and ds.task.dt == pytest.approx(0.1) and ds.landmark_names[0] == "hand"
    assert all(d.landmarks.shape == (d.n_samples, 3, 4, 4) for d in ds.demos)
    kin = KinematicModel.from_spec(ds.robot)
    res = fit(ds, kin, FitConfig(time_steps=8, seed=0))
    assert res.env_before_pruning["hand"] >= 0.95 and res.kept_landmarks == ("hand",)
    assert np.linalg.norm(res.model.tool.numpy() - TRUE_TOOL) < 0.02


def test_recordings_found_in_any_case_and_hidden_ones_skipped(tmp_path):
    """``joints.CSV`` (as some systems write it) was skipped without a word; a hidden copy was read."""
    from lfd.io.recordings import find_recordings
    shutil.copytree(DATA / "demo_01", tmp_path / "demo_01")
    for f in (tmp_path / "demo_01").iterdir():
        f.rename(f.with_name(f.name.upper()))
    shutil.copy(DATA / "demo_02" / "joints.csv", tmp_path / "demo_02_JOINTS.csv")
    shutil.copy(DATA / "demo_02" / "landmarks.csv", tmp_path / "demo_02_Landmarks.csv")
    shutil.copytree(DATA / "demo_03", tmp_path / ".demo_03")
    (tmp_path / "._demo_04_joints.csv").write_bytes(b"\x00\x05\x16\x07")
    found = find_recordings(tmp_path)
    assert [(n, j.name, None if lm is None else lm.name) for n, j, lm in found] == [
        ("demo_01", "JOINTS.CSV", "LANDMARKS.CSV"), ("demo_02", "demo_02_JOINTS.csv", "demo_02_Landmarks.csv")]


@pytest.mark.parametrize("layout", ["folders", "pairs", "folder-and-pair"])
def test_recordings_whose_names_differ_only_in_case_are_refused(tmp_path, layout):
    """With names matched in any case, ``DEMO_01`` beside ``demo_01`` would have hidden one of them;
    ``demo_01/`` beside ``demo_01_joints.csv`` is one recording counted twice."""
    from lfd.io.recordings import RecordingError, find_recordings
    if layout == "folders":
        shutil.copytree(DATA / "demo_01", tmp_path / "demo_01")
        shutil.copytree(DATA / "demo_02", tmp_path / "DEMO_01")
    else:
        for name in ("joints.csv", "landmarks.csv"):
            shutil.copy(DATA / "demo_01" / name, tmp_path / f"demo_01_{name}")
        if layout == "pairs":
            shutil.copy(DATA / "demo_02" / "joints.csv", tmp_path / "Demo_01_joints.csv")
        else:
            shutil.copytree(DATA / "demo_02", tmp_path / "demo_01")
    with pytest.raises(RecordingError, match="differ only in case|two recordings named"):
        find_recordings(tmp_path)


def test_a_spreadsheet_byte_order_mark_is_read(tmp_path):
    """Excel's "CSV UTF-8" starts with a byte-order mark: the first column was read as '\\ufefftime'
    and the recording refused for a missing 'time' column."""
    from lfd.io.recordings import find_recordings
    shutil.copytree(DATA / "demo_01", tmp_path / "demo_01")
    for name in ("joints.csv", "landmarks.csv"):
        f = tmp_path / "demo_01" / name
        f.write_bytes(b"\xef\xbb\xbf" + f.read_bytes())
    ds, _ = import_recordings(tmp_path, BAXTER_LEFT, 10.0)
    ref, _ = import_recordings(DATA, BAXTER_LEFT, 10.0)
    assert len(find_recordings(tmp_path)) == 1
    np.testing.assert_array_equal(ds.demos[0].q, ref.demos[0].q)


def test_a_semicolon_separated_csv_is_named(tmp_path):
    """A spreadsheet in a locale with ',' as its decimal mark writes ';' between fields: the header
    is one column, and the message says so instead of listing missing columns."""
    from lfd.io.recordings import RecordingError
    shutil.copytree(DATA / "demo_01", tmp_path / "demo_01")
    f = tmp_path / "demo_01" / "joints.csv"
    f.write_text("\n".join(";".join(c.replace(".", ",") for c in line.split(","))
                           for line in f.read_text().splitlines()) + "\n")
    with pytest.raises(RecordingError, match=r"joints.csv: the header 'time;left_s0;.* is one column: the "
                                             r"fields are separated by ';', not ','"):
        import_recordings(tmp_path, BAXTER_LEFT, 10.0)


def _write(path: Path, header, rows) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)


def test_resampling_matches_known_signals(tmp_path):
    """Joints sampled at irregular times are resampled linearly (sines, within the interpolation bound);
    a landmark turning at constant rate, read at 7 Hz, is slerped onto the 20 Hz samples; a
    landmark given in another frame (``T_base_frame``) lands in the base frame; custom columns in
    degrees through a ``JointColumns`` mapping."""
    rng = np.random.default_rng(0)
    t = np.sort(rng.uniform(0, 3, 200))
    t[0], t[-1] = 0.0, 3.0
    mid = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])  # the elbow (e1) bends only one way
    q = mid + 0.3 * np.sin(np.outer(t, np.arange(1, 8)) * 0.5)  # (S, 7) rad
    demo = tmp_path / "rec" / "d1"
    demo.mkdir(parents=True)
    _write(demo / "joints.csv", ["t", *(f"j{i}" for i in range(7))],
           [[f"{a:.6f}", *(f"{np.rad2deg(x):.8f}" for x in row)] for a, row in zip(t, q)])
    tl = np.arange(0, 3.01, 1 / 7)
    rot = Rotation.from_rotvec(np.outer(0.5 * tl, [0.0, 0.0, 1.0]))  # 0.5 rad/s about z
    rows = [[f"{a:.6f}", "cup", "0.1", f"{0.2 + 0.1 * a:.6f}", "0.0", *map(str, r)] for a, r in zip(tl, rot.as_quat())]
    rows.append(["0.0", "table", "1.0", "0.0", "0.0", "0", "0", "0", "1"])
    _write(demo / "landmarks.csv", ["time", "name", "x", "y", "z", "qx", "qy", "qz", "qw"], rows)
    cols = JointColumns(time="t", joints={j: f"j{i}" for i, j in enumerate(BAXTER_LEFT.joint_names)}, degrees=True)
    T_base_frame = np.eye(4)
    T_base_frame[:3, 3] = [0.5, 0.0, -0.2]
    ds, report = import_recordings(tmp_path / "rec", BAXTER_LEFT, 20.0, columns=cols, T_base_frame=T_base_frame)
    d = ds.demos[0]
    ts = np.arange(d.n_samples) / 20.0
    assert d.n_samples == 61 and report[0]["landmarks"] == "tracked"
    bound = np.diff(t).max() ** 2 / 8 * 0.3 * 3.5 ** 2  # linear interpolation: h^2 / 8 max|q''|
    assert np.abs(d.q - mid - 0.3 * np.sin(np.outer(ts, np.arange(1, 8)) * 0.5)).max() <= bound
    cup = d.landmarks[:, ds.landmark_names.index("cup")]
    assert np.allclose(cup[:, :3, 3], np.stack([0.6 + 0 * ts, 0.2 + 0.1 * ts, -0.2 + 0 * ts], axis=1), atol=1e-5)
    angle = Rotation.from_matrix(cup[:, :3, :3]).as_euler("xyz")[:, 2]
    assert np.abs(angle - 0.5 * ts).max() < 1e-6  # slerp between readings of a constant turn is exact
    table = d.landmarks[:, ds.landmark_names.index("table")]
    assert np.allclose(table[:, :3, 3], [1.5, 0.0, -0.2])  # read once: held still, in the base frame


def _corrupt_joints(folder: Path, fn, header: bool = False) -> None:
    path = folder / "demo_02" / "joints.csv"
    rows = list(csv.reader(path.open()))
    if header:
        rows = fn(rows)
        _write(path, rows[0], rows[1:])
    else:
        _write(path, rows[0], fn(rows[1:]))


def _corrupt_landmarks(folder: Path, fn) -> None:
    path = folder / "demo_03" / "landmarks.csv"
    rows = list(csv.reader(path.open()))
    _write(path, rows[0], fn(rows[1:]))


def _set(rows, i, col, value):
    rows[i][col] = value
    return rows


def _swap(rows, i):
    rows[i], rows[i + 1] = rows[i + 1], rows[i]
    return rows


def _glitch(rows):
    """One reading of the tracked hand, half-way through, 4 m off (a tracker's glitch)."""
    hand = [i for i, x in enumerate(rows) if x[1] == "hand"]
    return _set(rows, hand[len(hand) // 2], 2, str(float(rows[hand[len(hand) // 2]][2]) + 4.0))


BAD = [
    ("missing-column", lambda d: _corrupt_joints(d, lambda r: [x[:3] + x[4:] for x in r], header=True),
     "demo_02/joints.csv: missing column(s)"),
    ("not-a-number", lambda d: _corrupt_joints(d, lambda r: _set(r, 9, 3, "0.1.2")),
     "demo_02/joints.csv: row 11, column 'left_e0': '0.1.2' is not a finite number"),
    ("time-not-a-number", lambda d: _corrupt_joints(d, lambda r: _set(r, 9, 0, "")),
     "demo_02/joints.csv: row 11, column 'time': '' is not a finite number"),
    ("time-backwards", lambda d: _corrupt_joints(d, lambda r: _swap(r, 20)),
     "demo_02/joints.csv: time goes back at row 23"),
    ("gap", lambda d: _corrupt_joints(d, lambda r: r[:50] + r[90:]), "demo_02/joints.csv: a gap of"),
    ("joint-limit", lambda d: _corrupt_joints(d, lambda r: _set(r, 30, 4, "3.5")),
     "demo_02/joints.csv: row 32: joint left_e1 = 3.5 rad is outside its URDF limits"),
    ("quaternion", lambda d: _corrupt_landmarks(d, lambda r: _set(r, 4, 8, "0.5")),
     "demo_03/landmarks.csv: row 6: landmark 'hand': quaternion (qx, qy, qz, qw) has norm 0.5"),
    ("landmark-missing", lambda d: _corrupt_landmarks(d, lambda r: [x for x in r if x[1] != "head"]),
     "demo_03/landmarks.csv: landmarks ['hand', 'table_marker'] differ"),
    ("track-short", lambda d: _corrupt_landmarks(d, lambda r: [x for x in r if x[1] != "hand" or float(x[0]) < 1003]),
     "demo_03/landmarks.csv: landmark 'hand' is read from"),
    ("no-landmarks", lambda d: (d / "demo_03" / "landmarks.csv").unlink(), "no landmark recording beside it"),
    ("one-row", lambda d: _corrupt_joints(d, lambda r: r[:1]),  # was "the arm never moved"
     "demo_02/joints.csv: 1 reading(s) over 0 s, shorter than one sample interval at 10 Hz"),
    ("header-repeats", lambda d: _corrupt_joints(d, lambda r: [[("left_s0" if c == "left_gripper" else c) for c in r[0]]] + r[1:],
                                               header=True),
     "demo_02/joints.csv: the header repeats column(s)"),  # the first copy was read without a word
    ("millimetres", lambda d: _corrupt_landmarks(d, lambda r: [x[:2] + [str(float(v) * 1000) for v in x[2:5]] + x[5:]
                                                       for x in r]),
     "m from the robot's base, more than 20 m (millimetres given as metres"),  # was imported as metres
]


@pytest.mark.parametrize("corrupt,fragment", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_a_bad_recording_is_refused_in_one_line_and_nothing_is_written(tmp_path, capsys, corrupt, fragment):
    src = tmp_path / "rec"
    shutil.copytree(DATA, src)
    corrupt(src)
    r = _import(capsys, src, tmp_path / "out")
    assert r.returncode == 2 and fragment in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert not (tmp_path / "out").exists() and [p.name for p in tmp_path.iterdir()] == ["rec"]


def test_command_line_refusals(tmp_path, capsys):
    (tmp_path / "out").mkdir()
    assert "exists already" in _import(capsys, DATA, tmp_path / "out").stderr
    assert "--reference sink: not among" in _import(capsys, DATA, tmp_path / "o2", "--reference", "sink").stderr
    (tmp_path / "robot.json").write_text(json.dumps({"name": "x"}))
    r = _import(capsys, DATA, tmp_path / "o3", "--robot-json", str(tmp_path / "robot.json"))
    assert r.returncode == 2 and "--robot-json" in r.stderr
    spec = {**BAXTER_LEFT.to_dict(), "urdf": str(resolve_urdf(BAXTER_LEFT.urdf))}
    (tmp_path / "robot_rel.json").write_text(json.dumps({**spec, "urdf": os.path.relpath(spec["urdf"])}))
    r = _import(capsys, DATA, tmp_path / "o_rel", "--robot-json", str(tmp_path / "robot_rel.json"))
    assert r.returncode == 0, r.stderr  # a relative URDF path is stored absolute: training elsewhere finds it
    assert Path(load_demos(tmp_path / "o_rel").robot.urdf) == Path(spec["urdf"])
    assert "no recordings" in _import(capsys, tmp_path / "out", tmp_path / "o4").stderr
    (tmp_path / "afile").write_text("x")  # --out under a file was a FileExistsError traceback
    assert "afile: a file, not a folder of recordings" in _import(capsys, tmp_path / "afile", tmp_path / "o8").stderr
    r = _import(capsys, DATA, tmp_path / "afile" / "sub")
    assert r.returncode == 2 and "--out" in r.stderr and r.stderr.count("\n") == 1, r.stderr
    # bad numbers: one line each, not a traceback (NaN in the pose was a scipy error; 1e7 Hz filled the memory)
    for extra, fragment in ((("--frame-pose", "0", "0", "nan", "0", "0", "0", "1"), "--frame-pose needs 7 finite numbers"),
                            (("--frame-pose", "0", "0", "0", "0", "0", "0", "nan"), "--frame-pose needs 7 finite numbers"),
                            (("--rate", "1e7"), "--rate must be within [1, 1000] Hz"),
                            (("--rate", "0.5"), "--rate must be within [1, 1000] Hz"),
                            (("--max-gap", "0"), "--max-gap must be positive"),  # named 'max_gap' before
                            (("--trim-pauses", "-1"), "--trim-pauses at least 0"),
                            # a tolerance as large as the motion left nothing (0.5: an IndexError) or
                            # everything (100: imported untrimmed without a word)
                            (("--trim-pauses", "0.5"), "no motion is left once the pauses are trimmed"),
                            (("--trim-pauses", "100"), "no motion is left once the pauses are trimmed")):
        r = _import(capsys, DATA, tmp_path / "o5", *extra)
        assert r.returncode == 2 and fragment in r.stderr and r.stderr.count("\n") == 1, (extra, r.stderr)
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)  # a RecursionError traceback
    for option in ("--robot-json", "--columns"):
        r = _import(capsys, DATA, tmp_path / "o9", option, str(tmp_path / "deep.json"))
        assert r.returncode == 2 and (option in r.stderr or "deep.json" in r.stderr) and r.stderr.count("\n") == 1, r.stderr
    (tmp_path / "cols.json").write_text(json.dumps({"degrees": "false"}))  # was read as degrees=True
    r = _import(capsys, DATA, tmp_path / "o6", "--columns", str(tmp_path / "cols.json"))
    assert r.returncode == 2 and "'degrees' must be true or false, got 'false'" in r.stderr, r.stderr
    for k, (mapping, fragment) in enumerate((
            ({"joints": {"left_s9": "j0"}}, "names joint(s) ['left_s9'], which robot"),  # a misspelt key was ignored
            ({"joints": {"left_s1": "left_s0"}}, "reads column(s) ['left_s0'] for more than one joint"),
            ({"joints": {"left_s0": None}}, "column names must be non-empty strings"))):  # looked up 'None'
        (tmp_path / f"cols{k}.json").write_text(json.dumps(mapping))
        r = _import(capsys, DATA, tmp_path / f"o7{k}", "--columns", str(tmp_path / f"cols{k}.json"))
        assert r.returncode == 2 and fragment in r.stderr and r.stderr.count("\n") == 1, (mapping, r.stderr)


def test_angles_recorded_modulo_a_turn_are_unwrapped_into_the_limits(tmp_path):
    """A recorder that reports angles in [0, 2 pi): the wrist roll passing through 0 jumps from
    ~0 to ~2 pi and a negative joint reads 2 pi less; the import gives the continuous angles."""
    t = np.linspace(0, 2, 41)
    q = np.tile([0.1, -0.5, -0.3, 1.2, 0.2, 1.0, 0.0], (len(t), 1))
    q[:, 6] = np.linspace(0.4, -0.4, len(t))  # w2 passes through 0
    q[:, 1] = -0.5  # s1 negative throughout
    recorded = np.mod(q, 2 * np.pi)
    demo = tmp_path / "rec" / "d1"
    demo.mkdir(parents=True)
    names = list(BAXTER_LEFT.joint_names)
    _write(demo / "joints.csv", ["time", *names], [[f"{a:.3f}", *(f"{x:.6f}" for x in row)] for a, row in zip(t, recorded)])
    _write(demo / "landmarks.csv", ["time", "name", "x", "y", "z", "qx", "qy", "qz", "qw"],
           [["0.0", "bowl", "0.8", "0.3", "0.0", "0", "0", "0", "1"]])
    ds, _ = import_recordings(tmp_path / "rec", BAXTER_LEFT, 20.0)
    assert np.abs(ds.demos[0].q - q).max() < 1e-5


def test_a_task_at_another_interval_than_the_rate_is_refused():
    """rate=10 with TaskSpec(dt=0.02) gave samples 0.1 s apart and a model whose task.dt was 0.02."""
    from lfd.io.recordings import RecordingError
    from lfd.learning.tasks import TaskSpec
    with pytest.raises(RecordingError, match=r"^task 'handover': dt=0.02 differs from the demonstrations' sampling "
                                             r"interval dt=0.1 .*; at rate=10 Hz the samples are 0.1 s apart$"):
        import_recordings(DATA, BAXTER_LEFT, 10.0, task=TaskSpec(name="handover", dt=0.02, time_steps=8))


def _scaled():
    T = np.eye(4)
    T[:3, :3] *= 2.0  # doubled every landmark's position
    return T


@pytest.mark.parametrize("frame", [np.eye(3), _scaled(), np.where(np.eye(4) > 0, np.nan, 0.0), "base"],
                         ids=["3x3", "scaled", "nan", "str"])
def test_a_landmark_frame_that_is_not_a_rigid_transform_is_refused(frame):
    from lfd.io.recordings import RecordingError
    with pytest.raises(RecordingError, match=r"^T_base_frame must be a rigid transform, a finite \(4, 4\) matrix"):
        import_recordings(DATA, BAXTER_LEFT, 10.0, T_base_frame=frame)


def test_joint_columns_degrees_must_be_true_or_false():
    """JointColumns(degrees="false") built in Python counted as degrees."""
    from lfd.io.recordings import RecordingError
    with pytest.raises(RecordingError, match=r"^JointColumns: 'degrees' must be true or false, got 'false'$"):
        JointColumns(degrees="false")
    assert JointColumns(degrees=np.bool_(True)).degrees is True


def test_arguments_of_the_wrong_kind_are_named():
    """A robot's name, a dict of columns, a task's name and a rate as text failed as AttributeError
    or Python's comparison TypeError, naming no argument."""
    from lfd.io.recordings import RecordingError
    with pytest.raises(TypeError, match=r"^robot must be a RobotSpec .*got 'baxter_left'$"):
        import_recordings(DATA, "baxter_left", 10.0)
    with pytest.raises(TypeError, match=r"^columns must be a JointColumns .*got dict$"):
        import_recordings(DATA, BAXTER_LEFT, 10.0, columns={"left_s0": "j0"})
    with pytest.raises(TypeError, match=r"^task must be a TaskSpec or None .*got 'powder'$"):
        import_recordings(DATA, BAXTER_LEFT, 10.0, task="powder")
    for kw in ({"rate": "10"}, {"rate": 10.0, "trim": "0.01"}, {"rate": 10.0, "max_gap": None}):
        with pytest.raises(RecordingError, match=r"^rate, max_gap, trim and smooth must be numbers"):
            import_recordings(DATA, BAXTER_LEFT, **kw)
    ds, _ = import_recordings(DATA, BAXTER_LEFT, 10, trim=0)  # whole numbers are numbers
    assert abs(ds.dt - 0.1) < 1e-6


def test_a_stray_time_stamp_within_a_huge_max_gap_is_refused_not_allocated(tmp_path, capsys):
    """The last joint reading stamped 1e11 s (another unit), accepted by ``--max-gap 1e12``: the
    resampling asked for 7 TiB. A demonstration longer than ``MAX_DEMO_S`` is refused in one line."""
    import shutil
    src = tmp_path / "rec"
    shutil.copytree(DATA, src)
    path = src / "demo_01" / "joints.csv"
    lines = path.read_text().splitlines()
    head, last = lines[-1].split(",", 1)
    lines[-1] = "1e11," + last
    path.write_text("\n".join(lines) + "\n")
    r = _import(capsys, src, tmp_path / "out", "--max-gap", "1e12")
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "demo_01/joints.csv: the joints' readings span 1e+11 s, more than a demonstration of 3600 s" in r.stderr
