"""The kinesthetic demonstrator (sim/demos.py): the session's five powder demonstrations
(``powder_demos`` in conftest.py), drawn once for every test that needs recorded ones."""

import json

import numpy as np
import pytest
import torch

from lfd.robot.kinematics import KinematicModel
from sim import layout as L
from sim.demo_paths import TASK_POINTS, facing
from sim.demos import MIN_IN_BOWL, STRATIFIED_CANDIDATES, bowl_positions, generate, replay
from helpers import entry_point, run_cli
OTHER_POINT = (0.0, 0.02, 0.12)  # on the spoon's handle, not the default


@pytest.fixture(scope="module")
def kin():
    return KinematicModel.from_spec(dtype=torch.float64)


@pytest.fixture(scope="module")
def powder(powder_demos):
    return powder_demos


def _load(path):
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def test_files_in_the_leads_format(powder):
    out, paths, _ = powder
    assert len(paths) == 5 and all(p.is_file() for p in paths)
    d = _load(paths[0])
    assert set(d) == {"q", "dt", "joint_names", "landmark_poses", "landmark_names", "robot"}
    assert d["q"].shape[1] == 7 and d["landmark_poses"].shape == (5, 4, 4)
    assert str(d["landmark_names"][0]) == "bowl"
    truth = json.loads((out / "ground_truth.json").read_text())
    assert truth["tool_point"] == list(TASK_POINTS["powder"]) and truth["bowl_landmark"] == "bowl"
    assert (out / "task.json").is_file()


def test_velocity_and_joint_limits(powder, kin):
    _, paths, _ = powder
    lo, hi, vel = kin.lower.numpy(), kin.upper.numpy(), kin.velocity.numpy()
    for p in paths:
        d = _load(p)
        q, dt = d["q"], float(d["dt"])
        assert np.all(q >= lo) and np.all(q <= hi)
        assert np.all(np.abs(np.diff(q, axis=0)) <= vel * dt + 1e-12)


def test_demonstrations_differ_in_duration_and_time_profile(powder):
    _, _, kept = powder
    a, b = kept[:2]
    assert abs(a.path.duration - b.path.duration) > 0.1
    # time profile: the phase reached at the same fraction of the duration differs
    frac = np.linspace(0, 1, 50)
    ua = np.interp(frac, a.path.t / a.path.duration, a.path.u)
    ub = np.interp(frac, b.path.t / b.path.duration, b.path.u)
    assert np.abs(ua - ub).max() > 0.3


def test_a_saved_demonstration_replays(powder):
    """The file as saved (``q``, ``dt``) pours into the bowl without a hit when replayed in a new
    world with its scene (every demonstration was replayed so before it was kept: one suffices
    to check what the file holds)."""
    from sim.world import World
    _, paths, kept = powder
    d = _load(paths[0])
    with World("powder") as world:
        for name, pos in kept[0].placements.items():
            world.place_object(name, pos)
        in_bowl, hits = replay(world, d["q"], float(d["dt"]))
    assert hits == [] and in_bowl >= MIN_IN_BOWL


def _tracks(kin, q, T_world_tool, tool_point):
    T = kin.fk(torch.as_tensor(q)).numpy()
    pw = T[:, :3, 3] + np.einsum("sij,j->si", T[:, :3, :3], np.asarray(tool_point))
    return np.linalg.norm(pw - T_world_tool[:, :3, 3], axis=1).max()


def test_default_task_point_tracks_the_path(powder, kin):
    _, _, kept = powder
    for a in kept:
        assert _tracks(kin, a.q, a.path.T_world_tool, TASK_POINTS["powder"]) < 0.02  # IK + joint noise
        assert _tracks(kin, a.q, a.path.T_world_tool, OTHER_POINT) > 0.03


@pytest.mark.slow
def test_task_point_changes_the_followed_point(tmp_path, kin):
    kept = []
    generate("powder", tmp_path, n=1, seed=5, task_point=OTHER_POINT, progress=False, keep_attempts=kept)
    a = kept[0]
    assert _tracks(kin, a.q, a.path.T_world_tool, OTHER_POINT) < 0.02
    assert _tracks(kin, a.q, a.path.T_world_tool, TASK_POINTS["powder"]) > 0.03
    truth = json.loads((tmp_path / "ground_truth.json").read_text())
    assert truth["tool_point"] == list(OTHER_POINT)
    assert truth["roll_deg"] == 120.0  # the demonstrator's nominal roll is recorded (the powder's default)


@pytest.mark.parametrize("args, msg", [
    (["--task", "stir", "--out", "X"], "--task"),
    (["--task", "powder", "--n", "0", "--out", "X"], "--n"),
    (["--task", "powder", "--task-point", "0", "0", "nan", "--out", "X"], "--task-point"),
    (["--task", "pour", "--roll", "200", "--out", "X"], "--roll"),
    (["--task", "pour", "--roll", "nan", "--out", "X"], "--roll"),
    (["--task", "powder", "--seed", "-1", "--out", "X"], "--seed must be in [0, 2**63)"),  # a numpy traceback
    (["--task", "powder", "--out", "HELD"], "already holds demonstrations"),  # mixed two sets and a ground truth
    (["--task", "powder", "--plot", "paths.txt", "--out", "X"], "--plot must name a .png file"),  # after the drawing
    (["--task", "powder", "--out", ""], "--out: an empty path"),  # wrote the set into the current folder
])
def test_cli_bad_input_is_one_line_and_exit_2(tmp_path, capsys, args, msg):
    (tmp_path / "held").mkdir()
    (tmp_path / "held" / "demo_000.npz").write_bytes(b"")
    args = [{"X": str(tmp_path / "out"), "HELD": str(tmp_path / "held")}.get(a, a) for a in args]
    r = run_cli(*entry_point("python -m sim.demos"), args, capsys)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and msg in lines[0]


@pytest.mark.parametrize("task,asked,placement", [("powder", "uniform", "uniform"),
                                                  ("powder", "stratified", "stratified"),
                                                  ("powder", None, "uniform"), ("pour", None, "stratified")])
def test_bowl_is_kept_through_rejected_attempts(tmp_path, monkeypatch, task, asked, placement):
    """A rejected attempt is redrawn for the same bowl (redrawing the bowl would bias the set);
    the bowls are the placement's own (without one asked, the task's default), and uniform ones
    are the draws the demonstrator always made (one ``centre + uniform(-h, h, 2)`` per
    demonstration, before its attempts)."""
    import sim.demos as D
    from sim.demo_paths import draw_path

    seen = []

    def fake(world, kin, fns, task, bowl_xy, tool_point, dt, rng, roll_deg=None):  # draws nothing from rng
        seen.append(tuple(bowl_xy))
        path = draw_path(task, bowl_xy, np.r_[0.7, 0.8, 0.0, 0.3], dt, np.random.default_rng(99))
        fail = "test rejection" if len(seen) % 3 else ""
        return D.DemoAttempt(np.tile(L.HOME_Q, (5, 1)), path, {}, fail, 1.0)

    monkeypatch.setattr(D, "_draw_one", fake)
    D.generate(task, tmp_path, n=3, seed=4, progress=False, placement=asked)
    assert len(seen) == 9
    assert all(seen[3 * i] == seen[3 * i + 1] == seen[3 * i + 2] for i in range(3))
    bowls = np.array(seen[::3])  # (3, 2)
    rng = np.random.default_rng(4)
    if placement == "uniform":
        old = np.array([np.asarray(L.SQUARE_CENTER_XY) + rng.uniform(-L.SQUARE_HALF, L.SQUARE_HALF, 2)
                        for _ in range(3)])
        assert np.array_equal(bowls, old)
    else:
        assert np.array_equal(bowls, bowl_positions(3, rng, "stratified"))
    truth = json.loads((tmp_path / "ground_truth.json").read_text())
    assert truth["placement"] == placement and np.allclose(truth["bowl_xy"], bowls)


@pytest.mark.parametrize("stop", [RuntimeError, KeyboardInterrupt])
@pytest.mark.parametrize("existing", [False, True])
def test_an_interrupted_set_leaves_no_demonstration_behind(tmp_path, monkeypatch, stop, existing):
    """The demonstrator stops at the third of four demonstrations (it cannot draw it, or Ctrl-C):
    nothing of the set reaches ``out`` (a later ``lfd-train`` would have learned from the first
    two as if they were the set), no hidden work folder is left, and torch's thread count is the
    caller's again. Finished, the set is all there, in a new folder or beside a file that was
    already in it."""
    import torch

    import sim.demos as D
    from lfd.learning.demos import demo_files
    from sim.demo_paths import draw_path

    calls, stops = [], [stop]

    def fake(world, kin, fns, task, bowl_xy, tool_point, dt, rng, roll_deg=None):
        calls.append(1)
        if stops and len(calls) == 3:
            raise stops[0]("stopped at the third")
        path = draw_path(task, bowl_xy, np.r_[0.7, 0.8, 0.0, 0.3], dt, np.random.default_rng(99))
        return D.DemoAttempt(np.tile(L.HOME_Q, (5, 1)), path, {}, "", 1.0)

    monkeypatch.setattr(D, "_draw_one", fake)
    out = tmp_path / "set"
    if existing:
        out.mkdir()
        (out / "README.txt").write_text("mine")
    threads = torch.get_num_threads()
    with pytest.raises(stop):
        D.generate("powder", out, n=4, seed=0, progress=False)
    assert demo_files(out) == [] and not (out / "task.json").exists() and sorted(p.name for p in tmp_path.iterdir()) == (["set"] if existing else [])
    assert torch.get_num_threads() == threads
    calls.clear()
    stops.clear()
    paths = D.generate("powder", out, n=4, seed=0, progress=False)
    assert [p.name for p in paths] == [f"demo_{i:03d}.npz" for i in range(4)] and demo_files(out) == paths
    assert (out / "task.json").is_file() and (out / "ground_truth.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["set"]
    assert (out / "README.txt").is_file() == existing


@pytest.mark.parametrize("n", [1, 5, 11, 40])
def test_stratified_bowls_put_one_bowl_in_each_strip(n):
    """A Latin hypercube: each of the n strips of the square in x, and each in y, holds one bowl."""
    c, h = np.asarray(L.SQUARE_CENTER_XY), L.SQUARE_HALF
    for seed in range(20):
        b = bowl_positions(n, np.random.default_rng(seed), "stratified")
        assert b.shape == (n, 2)
        u = (b - c + h) / (2 * h)  # (n, 2) in [0, 1]
        assert np.all((u >= 0) & (u <= 1))
        for axis in range(2):
            assert sorted(np.floor(u[:, axis] * n).astype(int).tolist()) == list(range(n))


def _latin_hypercube(n, rng):
    """One plain Latin hypercube of n bowls, as ``bowl_positions`` draws each candidate."""
    c, h = np.asarray(L.SQUARE_CENTER_XY), L.SQUARE_HALF
    u = np.stack([(rng.permutation(n) + rng.uniform(0.0, 1.0, n)) / n for _ in range(2)], axis=1)
    return c + (2.0 * u - 1.0) * h


def _facing_spread(bowls):
    return float(np.degrees(np.std([facing(b) for b in bowls])))


def test_stratified_bowls_are_the_candidate_with_the_most_varied_facing():
    """The stratified set is the one of STRATIFIED_CANDIDATES Latin hypercubes, drawn from the same
    generator, that the demonstrator faces from the most varied directions; a single Latin
    hypercube can face its bowls within a narrow fan (seed 2: 13 degrees), the chosen set cannot."""
    for seed in range(30):
        rng = np.random.default_rng(seed)
        candidates = [_latin_hypercube(11, rng) for _ in range(STRATIFIED_CANDIDATES)]
        widest = max(candidates, key=_facing_spread)
        chosen = bowl_positions(11, np.random.default_rng(seed), "stratified")
        assert np.array_equal(chosen, widest)
    single = [_facing_spread(_latin_hypercube(11, np.random.default_rng(s))) for s in range(100)]
    chosen = [_facing_spread(bowl_positions(11, np.random.default_rng(s), "stratified")) for s in range(100)]
    assert min(single) < 15.0 and min(chosen) > 24.0


def test_stratified_bowls_still_cover_the_whole_square():
    """Choosing by the facing's spread favours the square's near right corner (the most turned
    facing), but leaves no part of it out: each of 4 x 4 cells still holds bowls."""
    c, h = np.asarray(L.SQUARE_CENTER_XY), L.SQUARE_HALF
    rng = np.random.default_rng(0)
    u = np.concatenate([(bowl_positions(11, rng, "stratified") - c + h) / (2 * h) for _ in range(300)])  # (3300, 2)
    hist = np.histogram2d(u[:, 0], u[:, 1], bins=4, range=[[0, 1], [0, 1]])[0] / len(u) * 16  # 1: uniform
    assert hist.min() > 0.1 and hist.max() < 3.0
    assert hist[0, 0] == hist.max()  # near the robot (small x), right of it (small y)


def test_uniform_bowls_can_leave_a_strip_empty_and_bad_placement_is_refused():
    """The reason for stratifying: 11 independent bowls often miss the strip nearest the robot."""
    c, h = np.asarray(L.SQUARE_CENTER_XY), L.SQUARE_HALF
    near = [np.any(bowl_positions(11, np.random.default_rng(s), "uniform")[:, 0] < c[0] - h + 2 * h / 11)
            for s in range(200)]
    assert 0.5 < np.mean(near) < 0.75  # 1 - (10/11)^11 = 0.65
    with pytest.raises(ValueError, match="placement must be one of"):
        bowl_positions(3, np.random.default_rng(0), "grid")


def _quadrants(bowls):
    c = np.asarray(L.SQUARE_CENTER_XY)
    b = np.asarray(bowls) - c
    assert np.all(np.abs(b) <= L.SQUARE_HALF + 1e-9)
    return {(bool(x > 0), bool(y > 0)) for x, y in b}


@pytest.mark.slow
@pytest.mark.parametrize("task", ["powder", "pour"])
def test_eleven_demonstrations_cover_the_square(tmp_path, kin, task):
    """11 demonstrations (each kept only after a successful replay) put bowls in >= 3 quadrants."""
    kept = []
    generate(task, tmp_path, n=11, seed=0, progress=False, keep_attempts=kept)
    truth = json.loads((tmp_path / "ground_truth.json").read_text())
    assert len(_quadrants(truth["bowl_xy"])) >= 3
    assert all(a.in_bowl >= MIN_IN_BOWL for a in kept)
    vel = kin.velocity.numpy()
    dt = kept[0].path.t[1] - kept[0].path.t[0]
    assert all(np.all(np.abs(np.diff(a.q, axis=0)) <= vel * dt + 1e-12) for a in kept)


@pytest.mark.parametrize("task", ["powder", "pour"])
def test_dump_roll_stays_within_the_demonstrators_spread(task):
    """The held dump / pour roll of a demonstration is DUMP_NOMINAL +- ROLL_SPREAD (the pitcher
    rolled well past the ~100 deg it needs to empty), and it varies between demonstrations; the
    scenario solvability check (sim.reach) uses the same nominal pose."""
    from sim.demo_paths import DUMP_NOMINAL, ROLL_SPREAD, draw_path

    nominal, spread = DUMP_NOMINAL[task][1], ROLL_SPREAD[task]
    rolls = np.array([np.rad2deg(draw_path(task, (0.8, 0.3), np.array([0.6, 0.5, 0.0, 0.0]), 0.1,
                                           np.random.default_rng(seed)).keyframes[5, 5])
                      for seed in range(30)])
    assert np.all(np.abs(rolls - nominal) <= spread + 1e-9)
    assert np.ptp(rolls) > spread  # drawn, not fixed
    if task == "pour":
        assert rolls.min() > 100.0


def test_a_demonstrator_who_tilts_less():
    """``roll_deg`` (``python -m sim.demos --roll``) is another demonstrator: the held roll is
    drawn around it, not around the task's nominal; the same seed draws the same path otherwise."""
    from sim.demo_paths import ROLL_SPREAD, draw_path

    def rolls(roll_deg):
        return np.array([np.rad2deg(draw_path("pour", (0.8, 0.3), np.array([0.6, 0.5, 0.0, 0.0]), 0.1,
                                              np.random.default_rng(seed), roll_deg=roll_deg).keyframes[5, 5])
                         for seed in range(20)])

    less, default = rolls(105.0), rolls(None)
    assert np.all(np.abs(less - 105.0) <= ROLL_SPREAD["pour"] + 1e-9)
    np.testing.assert_allclose(default - less, 10.0, atol=1e-9)  # the same draws, shifted by 115 - 105
    with pytest.raises(ValueError, match="roll"):
        draw_path("pour", (0.8, 0.3), np.array([0.6, 0.5, 0.0, 0.0]), 0.1, np.random.default_rng(0), roll_deg=30.0)


def test_ground_truth_names_where_the_demonstrator_aimed(powder, kin):
    """``reference_points`` holds the aim: the gripper-frame point that sat over the bowl's centre,
    at its rim, when each demonstration tilted most (mean over them). For the powder it lies
    below the scoop (the task point) by about the dumping height above the rim (4-7 cm, the spoon
    turned over), and carried by each demonstration's gripper at that moment it lands on the
    bowl's centre."""
    from sim.attitude import tool_tilt_deg
    from sim.demos import AIM_POINT

    out, _, kept = powder
    aim = np.array(json.loads((out / "ground_truth.json").read_text())["reference_points"][AIM_POINT])
    assert 0.02 < np.linalg.norm(aim - np.array(TASK_POINTS["powder"])) < 0.10
    for a in kept:
        T = kin.fk(torch.as_tensor(a.q)).numpy()
        i = int(np.argmax(tool_tilt_deg(T[:, :3, :3])))
        p = T[i, :3, :3] @ aim + T[i, :3, 3]
        rim = np.r_[a.path.bowl_xy, L.TABLE_TOP_Z + L.BOWL_HEIGHT]
        assert np.linalg.norm(p - rim) < 0.03  # the mean of two demonstrations' aims
