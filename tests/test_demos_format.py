"""The demonstration format: round trip, and every kind of broken file refused with its own message."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lfd.learning.demos import load_demos, save_demos

from lfd.learning.demoset import DemoFormatError, DemoSet
from lfd.robot.robots import BAXTER_LEFT
from lfd.learning.tasks import POWDER
from helpers import entry_point, rewrite_npz, run_cli, small_demoset
NAMES = ("bowl", "marker_1", "marker_2")


def _demoset(n=2, samples=30, seed=0) -> DemoSet:
    return small_demoset(n, samples, seed, ground_truth={"tool_point": [0, 0, 0.1]})


@pytest.fixture(scope="module")
def kin():
    from lfd.robot.kinematics import KinematicModel
    return KinematicModel.from_spec()


@pytest.fixture()
def good_dir(tmp_path):
    save_demos(tmp_path, _demoset())
    return tmp_path


_rewrite = rewrite_npz


def test_round_trip(good_dir, kin):
    ds = _demoset()
    loaded = load_demos(good_dir, kin=kin)
    assert loaded.landmark_names == NAMES
    assert loaded.joint_names == BAXTER_LEFT.joint_names
    assert loaded.task == POWDER
    assert loaded.ground_truth == {"tool_point": [0, 0, 0.1]}
    assert len(loaded.demos) == 2
    for a, b in zip(ds.demos, loaded.demos):
        np.testing.assert_array_equal(a.q, b.q)
        np.testing.assert_array_equal(a.landmarks, b.landmarks)
        assert a.dt == b.dt


def _bad_pose():
    T = np.tile(np.eye(4), (3, 1, 1))
    T[1, :3, :3] *= 1.5
    return T


S1 = _demoset().demos[1].n_samples  # samples of demo_001.npz, which the broken cases rewrite


def _tracked_bad_pose():
    T = np.tile(np.eye(4), (S1, 3, 1, 1))
    T[7, 1, :3, :3] *= 1.5
    return T


def _tracked_jump():
    """marker_1 read 8.5 m away at one sample (a tracking glitch), back at the next."""
    T = np.tile(np.eye(4), (S1, 3, 1, 1))
    T[10, 1, :3, 3] = [8.5, 0.0, 0.0]
    return T


def _millimetres():
    T = np.tile(np.eye(4), (3, 1, 1))
    T[:, :3, 3] = [850.0, 0.0, 0.0]
    return T


# (id, changes to demo_001.npz, expected message fragment)
BROKEN = [
    ("missing-q", {"q": None}, r"missing key\(s\) \['q'\]"),
    ("missing-landmarks", {"landmark_poses": None}, r"missing key\(s\) \['landmark_poses'\]"),
    ("q-1d", {"q": np.zeros(7)}, r"'q' must have 2 dimension"),
    ("q-columns", {"q": np.zeros((30, 6))}, r"'q' has 6 columns"),
    ("q-nan", {"q": np.full((30, 7), np.nan)}, r"'q' holds NaN"),
    ("q-inf", {"q": np.where(np.eye(30, 7) > 0, np.inf, 0.0)}, r"'q' holds NaN or infinite"),
    ("q-strings", {"q": np.array(["a"] * 7)}, r"'q' must be numeric"),
    ("q-limits", {"q": np.full((30, 7), 2.9)}, r"outside its limits"),
    ("too-short", {"q": np.zeros((5, 7))}, r"only 5 samples, fewer than the 24 time steps"),
    ("dt-zero", {"dt": np.float64(0.0)}, r"'dt' \(sampling interval, seconds\) must be positive"),
    ("dt-milliseconds", {"dt": np.float64(20.0)}, r"at most 1, got 20.0 \(milliseconds given as seconds\?\)"),
    ("dt-negative", {"dt": np.float64(-0.1)}, r"must be positive"),
    ("dt-differs", {"dt": np.float64(0.05)}, r"sampling interval dt=0.05 differs"),
    ("pose-shape", {"landmark_poses": np.zeros((3, 3, 4))}, r"must have shape \(3, 4, 4\)"),
    ("pose-count", {"landmark_poses": np.tile(np.eye(4), (2, 1, 1))}, r"must have shape \(3, 4, 4\)"),
    ("pose-not-rigid", {"landmark_poses": _bad_pose()}, r"'marker_1' pose is not a rigid transform"),
    ("pose-nan", {"landmark_poses": np.full((3, 4, 4), np.nan)}, r"'landmark_poses' holds NaN"),
    ("tracked-length", {"landmark_poses": np.tile(np.eye(4), (S1 - 1, 3, 1, 1))},
     rf"must have shape \(3, 4, 4\) or, tracked, \({S1}, 3, 4, 4\)"),
    ("pose-millimetres", {"landmark_poses": _millimetres()}, r"'bowl' is 850 m from the robot's base"),
    ("tracked-not-rigid", {"landmark_poses": _tracked_bad_pose()}, r"'marker_1' pose at sample 7 is not a rigid"),
    ("tracked-jump", {"landmark_poses": _tracked_jump()},
     r"'marker_1' moves 8.5 m between samples 9 and 10 \(85 m/s, more than 5 m/s"),
    ("motionless", {"q": np.tile([0.0, -0.5, 0.0, 1.2, 0.0, 0.5, 0.0], (S1, 1))},
     r"demonstration 'demo_001': no joint moves more than 0 rad: the arm never moved"),
    ("landmark-names", {"landmark_names": np.array(["bowl", "marker_1", "vase"])}, r"landmark_names .* differ"),
    ("landmark-dup", {"landmark_names": np.array(["bowl", "bowl", "vase"])}, r"repeats a name"),
    ("joint-order", {"joint_names": np.array(list(reversed(BAXTER_LEFT.joint_names)))}, r"joint_names .* differ"),
    ("robot-json", {"robot": np.array("not json")}, r"'robot' must be the JSON of a RobotSpec"),
    ("robot-deep", {"robot": np.array("[" * 100_000 + "]" * 100_000)}, r"'robot' must be the JSON of a RobotSpec"),
    ("robot-differs", {"robot": np.array(json.dumps({**BAXTER_LEFT.to_dict(), "end_link": "left_hand"}))},
     r"recorded on robot"),
    ("names-object", {"landmark_names": np.array(["bowl", 1, None], dtype=object)}, r"cannot read without pickle"),
    ("names-blank", {"landmark_names": np.array(["bowl", "marker_1", "  "])}, r"holds an empty name"),
]


@pytest.mark.parametrize("changes,match", [b[1:] for b in BROKEN], ids=[b[0] for b in BROKEN])
def test_broken_file_refused(good_dir, kin, changes, match):
    _rewrite(good_dir / "demo_001.npz", **changes)
    with pytest.raises(DemoFormatError, match=match) as info:
        load_demos(good_dir, kin=kin)
    assert "demo_00" in str(info.value)  # the message names the file


def test_one_recording_saved_twice_is_refused(good_dir, kin):
    """Two files with the same joint trajectory (a copy) would count twice in the model."""
    with np.load(good_dir / "demo_000.npz") as z:
        q0 = z["q"]
    _rewrite(good_dir / "demo_001.npz", q=q0)
    with pytest.raises(DemoFormatError, match=r"'demo_000' and 'demo_001' have the same joint trajectory"):
        load_demos(good_dir, kin=kin)
    _rewrite(good_dir / "demo_001.npz", q=q0 + 1e-4)  # a near copy is another recording
    assert len(load_demos(good_dir, kin=kin).demos) == 2


def test_a_landmark_moved_by_hand_is_not_a_glitch(good_dir, kin):
    """A tracked landmark carried 0.3 m in 1 s (0.3 m/s) passes the speed check."""
    T = np.tile(np.eye(4), (S1, 3, 1, 1))
    T[:, 0, 0, 3] = 0.5 + np.clip(np.arange(S1) - 10, 0, 10) * 0.03  # dt 0.1 s
    _rewrite(good_dir / "demo_001.npz", landmark_poses=T)
    assert load_demos(good_dir, kin=kin).demos[1].landmarks.shape == (S1, 3, 4, 4)


def test_unknown_joint_name(tmp_path, kin):
    ds = _demoset()
    bad = [*BAXTER_LEFT.joint_names[:-1], "left_w9"]
    for i, d in enumerate(ds.demos):
        from lfd.learning.demos import save_demonstration
        save_demonstration(tmp_path / f"d{i}.npz", d, bad, NAMES, BAXTER_LEFT)
    with pytest.raises(DemoFormatError, match=r"unknown joint name\(s\) \['left_w9'\]"):
        load_demos(tmp_path, kin=kin)


def test_not_a_zip_and_empty_folder(tmp_path, kin):
    with pytest.raises(DemoFormatError, match="/dev/null: neither a folder of demonstrations nor an .npz"):
        load_demos("/dev/null", kin=kin)
    with pytest.raises(DemoFormatError, match="no demonstration files"):
        load_demos(tmp_path, kin=kin)
    (tmp_path / "x.npz").write_bytes(b"this is not a zip file")
    with pytest.raises(DemoFormatError, match="not a readable .npz file"):
        load_demos(tmp_path, kin=kin)
    with pytest.raises(DemoFormatError, match="no such demonstration folder"):
        load_demos(tmp_path / "absent", kin=kin)


def test_hidden_files_skipped_and_the_suffix_read_in_any_case(good_dir, kin):
    """``._demo_000.npz`` (macOS resource forks on shared drives) is not a demonstration: it was
    loaded and refused as damaged; ``DEMO.NPZ`` is one."""
    (good_dir / "._demo_000.npz").write_bytes(b"\x00\x05\x16\x07 resource fork")
    (good_dir / "demo_001.npz").rename(good_dir / "DEMO_001.NPZ")
    loaded = load_demos(good_dir, kin=kin)
    assert len(loaded.demos) == 2
    np.testing.assert_array_equal(loaded.demos[1].q, _demoset().demos[1].q)  # in order of name, any case


@pytest.mark.parametrize("name", ["task.json", "ground_truth.json"])
def test_a_side_file_that_is_a_folder_or_a_broken_link_is_refused(good_dir, kin, name):
    """It was taken for absent: the model then named no task, and plan.py said the set had no task.json."""
    (good_dir / name).unlink(missing_ok=True)
    (good_dir / name).mkdir()
    with pytest.raises(DemoFormatError, match="not a readable file"):
        load_demos(good_dir, kin=kin)
    (good_dir / name).rmdir()
    (good_dir / name).symlink_to(good_dir / "absent.json")
    with pytest.raises(DemoFormatError, match="not a readable file"):
        load_demos(good_dir, kin=kin)


def test_a_task_name_no_option_can_give_is_refused(good_dir, kin):
    """'my task' passed the set check, but no --task value could then train it."""
    (good_dir / "task.json").write_text(json.dumps({**POWDER.to_dict(), "name": "my task"}))
    with pytest.raises(DemoFormatError, match="name of letters, digits"):
        load_demos(good_dir, kin=kin)


def test_cli_one_line_exit_2(good_dir, capsys):
    _rewrite(good_dir / "demo_001.npz", dt=np.float64(-1.0))
    r = run_cli(*entry_point("python -m lfd.learning.demos"), [good_dir], capsys)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert "must be positive" in r.stderr


def test_cli_notes_a_reference_landmark_the_set_does_not_sense(good_dir, capsys):
    """A task.json whose reference_landmark no file senses: the set is valid (exit 0), and the
    summary says which baseline it cannot serve; with a sensed one, no note."""
    r = run_cli(*entry_point("python -m lfd.learning.demos"), [good_dir], capsys)
    assert r.returncode == 0 and "note:" not in r.stdout
    (good_dir / "task.json").write_text(json.dumps({**POWDER.to_dict(), "reference_landmark": "kettle"}))
    r = run_cli(*entry_point("python -m lfd.learning.demos"), [good_dir], capsys)
    assert r.returncode == 0, r.stderr
    assert "reference_landmark 'kettle' is not among the landmarks" in r.stdout


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_random_corruption_loaded_or_refused(tmp_path_factory, kin, data):
    """Random byte-level and value-level corruptions: loaded correctly, or refused with DemoFormatError."""
    d = tmp_path_factory.mktemp("corrupt")
    save_demos(d, _demoset())
    target = d / "demo_000.npz"
    mode = data.draw(st.sampled_from(["bytes", "truncate", "value"]))
    if mode == "bytes":
        raw = bytearray(target.read_bytes())
        for _ in range(data.draw(st.integers(1, 20))):
            i = data.draw(st.integers(0, len(raw) - 1))
            raw[i] = data.draw(st.integers(0, 255))
        target.write_bytes(bytes(raw))
    elif mode == "truncate":
        raw = target.read_bytes()
        target.write_bytes(raw[: data.draw(st.integers(0, len(raw) - 1))])
    else:
        key = data.draw(st.sampled_from(["q", "dt", "landmark_poses"]))
        with np.load(target) as z:
            arr = z[key].astype(np.float64).copy()
        flat = arr.reshape(-1)
        i = data.draw(st.integers(0, flat.size - 1))
        flat[i] = data.draw(st.floats(allow_nan=True, allow_infinity=True))
        _rewrite(target, **{key: arr})
    try:
        ds = load_demos(d, kin=kin)
    except DemoFormatError:
        return
    for demo in ds.demos:  # whatever loads is valid
        assert np.all(np.isfinite(demo.q)) and np.all(np.isfinite(demo.landmarks))
        assert demo.dt > 0 and demo.q.shape[1] == 7


def test_subsample_keeps_every_kth_sample_and_scales_dt():
    ds = _demoset(n=3, samples=31)
    sub = ds.subsample(5)
    for d, s in zip(ds.demos, sub.demos):
        np.testing.assert_array_equal(s.q, d.q[::5])  # the first sample kept, then every 5th
        assert s.q.shape[0] == 7 and s.dt == pytest.approx(5 * d.dt)
        np.testing.assert_array_equal(s.landmarks, d.landmarks)
    assert sub.task.dt == pytest.approx(5 * ds.task.dt) and sub.task.time_steps == ds.task.time_steps
    assert replace(ds, task=replace(ds.task, subsample=5)).subsample(5).task.subsample == 1  # stride spent
    assert sub.landmark_names == ds.landmark_names and sub.ground_truth == ds.ground_truth
    assert ds.demos[0].q.shape[0] == 31 and ds.task.dt == POWDER.dt  # the original is untouched
    assert ds.subsample(1) is ds
    for bad in (0, -2, 1.5, True, "2"):
        with pytest.raises(ValueError, match="subsample stride must be a whole number"):
            ds.subsample(bad)


def test_task_subsample_round_trips_and_is_checked(tmp_path):
    from lfd.learning.tasks import POUR, TaskSpec
    POUR.save(tmp_path / "task.json")
    assert TaskSpec.load(tmp_path / "task.json") == POUR and POUR.subsample == 2
    old = POUR.to_dict()
    del old["subsample"]  # a task.json written before the field: every sample
    assert TaskSpec.from_dict(old).subsample == 1
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="TaskSpec.subsample must be a whole number"):
            replace(POUR, subsample=bad)


def test_task_restarts_round_trip_and_are_checked(tmp_path):
    """``TaskSpec.restarts``: saved and loaded; None (FitConfig's) for a task.json without it."""
    from lfd.learning.tasks import POUR, POWDER, TaskSpec
    POWDER.save(tmp_path / "task.json")
    assert TaskSpec.load(tmp_path / "task.json").restarts is None
    assert TaskSpec.from_dict(replace(POUR, restarts=np.int64(7)).to_dict()).restarts == 7
    old = POUR.to_dict()
    del old["restarts"]
    assert TaskSpec.from_dict(old).restarts is None
    for bad in (0, 2.5, True, "4"):
        with pytest.raises(ValueError, match="TaskSpec.restarts must be a whole number >= 1"):
            replace(POUR, restarts=bad)


def test_every_stride_option_takes_numpy_integers_and_refuses_the_rest():
    # one rule for DemoSet.subsample, TaskSpec.subsample and FitConfig.subsample: a stride read
    # from an array (np.int64) is a whole number and is stored as a plain int (JSON-serialisable)
    from lfd.learning.learn import FitConfig
    from lfd.learning.tasks import POUR
    ds = _demoset(n=2, samples=12)
    assert [s.q.shape[0] for s in ds.subsample(np.int64(3)).demos] == [len(d.q[::3]) for d in ds.demos]
    for made in (replace(POUR, subsample=np.int64(3)), FitConfig(subsample=np.int64(3))):
        assert made.subsample == 3 and type(made.subsample) is int
    for bad in (0, -1, 2.0, np.float64(2), True, "2", None):
        with pytest.raises(ValueError, match="must be a whole number >= 1"):
            FitConfig(subsample=bad)


def test_tracked_landmarks_load_and_subsample_with_their_samples(good_dir, kin):
    """``landmark_poses (S, Z, 4, 4)``: one pose per sample (a tracked, moving landmark) loads
    beside files that hold one pose per landmark, and thinning the samples thins the poses."""
    T = np.tile(np.eye(4), (S1, 3, 1, 1))
    T[:, 0, 0, 3] = np.linspace(0.5, 0.9, S1)  # the bowl slides 0.4 m during the demonstration
    _rewrite(good_dir / "demo_001.npz", landmark_poses=T)
    ds = load_demos(good_dir, kin=kin)
    assert ds.demos[0].landmarks.shape == (3, 4, 4)
    np.testing.assert_array_equal(ds.demos[1].landmarks, T)
    thin = ds.subsample(3)
    assert thin.demos[1].landmarks.shape == (len(T[::3]), 3, 4, 4) and thin.demos[0].landmarks.shape == (3, 4, 4)
    np.testing.assert_array_equal(thin.demos[1].landmarks, T[::3])


def test_names_given_as_one_string_are_refused(tmp_path):
    """save_demonstration(landmark_names="bowl") wrote 4 one-letter names; the load blamed the poses."""
    from lfd.learning.demos import save_demonstration
    ds = _demoset()
    with pytest.raises(ValueError, match=r"landmark_names must be a list of names, got the string 'bowl'"):
        save_demonstration(tmp_path / "d.npz", ds.demos[0], ds.joint_names, "bowl", ds.robot)
    with pytest.raises(ValueError, match=r"joint_names must be a list of names, got the string 'left_s0'"):
        save_demonstration(tmp_path / "d.npz", ds.demos[0], "left_s0", NAMES, ds.robot)
    assert not list(tmp_path.iterdir())


def test_save_refuses_what_load_would_and_makes_the_folder(tmp_path):
    """save_demonstration wrote NaN, a transposed q, 6 of 7 columns, a negative dt, no samples and
    3 poses for 2 names, each refused only when the set was loaded; and it failed on a folder
    not yet made (the README's example). Now each is refused before anything is written."""
    from lfd.learning.demos import save_demonstration
    from lfd.learning.demoset import Demonstration
    d = _demoset().demos[0]
    q = np.array(d.q)
    nan = q.copy()
    nan[2, 3] = np.nan
    cases = [(Demonstration(q=nan, dt=d.dt, landmarks=d.landmarks), "holds NaN"),
             (Demonstration(q=q.T, dt=d.dt, landmarks=d.landmarks), "columns but 'joint_names' names 7"),
             (Demonstration(q=q[:, :6], dt=d.dt, landmarks=d.landmarks), "6 columns"),
             (Demonstration(q=q, dt=-0.1, landmarks=d.landmarks), "must be positive"),
             (Demonstration(q=q[:0], dt=d.dt, landmarks=d.landmarks), "at least 2"),
             (Demonstration(q=q, dt=d.dt, landmarks=np.tile(np.eye(4), (len(NAMES) + 1, 1, 1))), "must have shape")]
    for demo, fragment in cases:
        with pytest.raises(DemoFormatError, match=fragment):
            save_demonstration(tmp_path / "new" / "d.npz", demo, BAXTER_LEFT.joint_names, NAMES, BAXTER_LEFT)
    assert not list(tmp_path.iterdir())
    path = save_demonstration(tmp_path / "new" / "deeper" / "d", d, BAXTER_LEFT.joint_names, NAMES, BAXTER_LEFT)
    assert path == tmp_path / "new" / "deeper" / "d.npz" and path.is_file()
    np.testing.assert_array_equal(load_demos(path.parent, time_steps=2).demos[0].q, q)


def test_a_demonstration_holds_lists_as_arrays():
    """Demonstration(q=list).n_samples was an AttributeError."""
    from lfd.learning.demoset import Demonstration
    d = _demoset().demos[0]
    listed = Demonstration(q=d.q.tolist(), dt=d.dt, landmarks=d.landmarks.tolist())
    assert listed.n_samples == d.n_samples and isinstance(listed.landmarks, np.ndarray)
    assert np.array_equal(listed.q, d.q)


def test_load_demos_checks_its_arguments(good_dir, kin):
    """time_steps=0 or 2.5 was taken as given; a NaN limit_tolerance turned the limit check off."""
    for bad in (0, 1, 2.5, True):
        with pytest.raises(ValueError, match=rf"^time_steps must be a whole number >= 2, got {bad!r}$"):
            load_demos(good_dir, time_steps=bad, kin=kin)
    for bad in (float("nan"), float("inf"), -0.1, "0.02", None):
        with pytest.raises(ValueError, match=rf"^limit_tolerance must be a finite angle >= 0 \(rad\), got {bad!r}$"):
            load_demos(good_dir, kin=kin, limit_tolerance=bad)
    assert len(load_demos(good_dir, time_steps=np.int64(2), kin=kin, limit_tolerance=0).demos) == 2


def test_a_sampling_interval_stored_in_single_precision_matches_its_task(good_dir):
    """``np.float32(0.1)`` is 0.10000000149: recordings written in single precision were refused
    against their own task.json (dt=0.1); a real difference is still refused."""
    files = sorted(good_dir.glob("*.npz"))
    dt = float(np.load(files[0])["dt"])
    for f in files:
        _rewrite(f, dt=np.float32(dt))
    assert len(load_demos(good_dir).demos) == len(files)
    _rewrite(files[0], dt=np.float64(dt * 1.001))
    with pytest.raises(DemoFormatError, match="dt="):
        load_demos(good_dir)
