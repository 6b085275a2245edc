"""The kinesthetic demonstrator (sim/demos.py): generated once per module, small n."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from lfd.kinematics import KinematicModel
from sim import layout as L
from sim.demo_paths import TASK_POINTS
from sim.demos import MIN_IN_BOWL, generate, replay

ROOT = Path(__file__).resolve().parent.parent
OTHER_POINT = (0.0, 0.02, 0.12)  # on the spoon's handle, not the default


@pytest.fixture(scope="module")
def kin():
    return KinematicModel.from_spec(dtype=torch.float64)


@pytest.fixture(scope="module")
def powder(tmp_path_factory):
    out = tmp_path_factory.mktemp("powder")
    kept = []
    paths = generate("powder", out, n=2, seed=3, progress=False, keep_attempts=kept)
    return out, paths, kept


def _load(path):
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def test_files_in_the_leads_format(powder):
    out, paths, _ = powder
    assert len(paths) == 2 and all(p.is_file() for p in paths)
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
    a, b = kept
    assert abs(a.path.duration - b.path.duration) > 0.1
    # time profile: the phase reached at the same fraction of the duration differs
    frac = np.linspace(0, 1, 50)
    ua = np.interp(frac, a.path.t / a.path.duration, a.path.u)
    ub = np.interp(frac, b.path.t / b.path.duration, b.path.u)
    assert np.abs(ua - ub).max() > 0.3


def test_each_demonstration_replays(powder):
    from sim.world import World
    _, paths, kept = powder
    with World("powder") as world:
        for p, a in zip(paths, kept):
            d = _load(p)
            for name, pos in a.placements.items():
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


@pytest.mark.parametrize("args, msg", [
    (["--task", "stir", "--out", "X"], "--task"),
    (["--task", "powder", "--n", "0", "--out", "X"], "--n"),
    (["--task", "powder", "--task-point", "0", "0", "nan", "--out", "X"], "--task-point"),
])
def test_cli_bad_input_is_one_line_and_exit_2(tmp_path, args, msg):
    args = [a if a != "X" else str(tmp_path / "out") for a in args]
    r = subprocess.run([sys.executable, "-m", "sim.demos", *args], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and msg in lines[0]
