"""The tool's tilt (sim.attitude): the demonstrator's roll read back from rotations, from the
learned kinematics against PyBullet's, and from recorded demonstrations."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from lfd.robot.kinematics import KinematicModel
from sim.attitude import demo_tilt, tool_tilt_deg
from sim.demo_paths import tool_rotation

# a recorded demonstration's largest tilt against the roll drawn for it (IK and tracking; the
# session's five differ by at most 0.5 deg)
TILT_TOLERANCE_DEG = 2.0


def test_tilt_is_the_roll_of_a_level_tool():
    """For the demonstrator's tool frames ``R_level(yaw) R_x(0) R_z(roll)`` the tilt is the roll,
    whatever the facing; a few degrees of pitch change it by at most the pitch."""
    rng = np.random.default_rng(0)
    yaw, roll = rng.uniform(-np.pi, np.pi, 50), rng.uniform(0, np.pi, 50)
    np.testing.assert_allclose(tool_tilt_deg(tool_rotation(yaw, np.zeros(50), roll)), np.degrees(roll), atol=1e-9)
    pitch = np.radians(rng.uniform(-8, 8, 50))
    assert np.all(np.abs(tool_tilt_deg(tool_rotation(yaw, pitch, roll)) - np.degrees(roll)) <= 8 + 1e-9)
    with pytest.raises(ValueError, match="3, 3"):
        tool_tilt_deg(np.eye(4))


def test_tilt_from_the_kinematics_equals_pybullets():
    """The executor's tilt (lfd's forward kinematics of the joints) is the tilt of PyBullet's own
    tool frame, within 0.01 deg, over random configurations."""
    from sim.world import World

    kin = KinematicModel.from_spec(dtype=torch.float64)
    Q = kin.sample_uniform(20, generator=torch.Generator().manual_seed(0)).numpy()
    with World("powder", n_particles=0) as world:
        ours, theirs = [], []
        for q in Q:
            world.set_q(q)
            theirs.append(tool_tilt_deg(world.T_world_tool()[:3, :3]))
            ours.append(tool_tilt_deg(kin.fk(torch.as_tensor(q))[:3, :3].numpy()))
    np.testing.assert_allclose(ours, theirs, atol=1e-2)
    assert np.ptp(theirs) > 60  # the configurations tilt the tool in many ways


def test_demo_tilt_reads_the_demonstrators_roll(powder_demos, tmp_path):
    """Each demonstration's largest tilt, by forward kinematics of its recorded joints, is the
    roll the demonstrator drew for it, one by one, not only on average; an empty folder gives NaN."""
    folder, _, kept = powder_demos
    t = demo_tilt(folder)
    drawn = np.array([np.rad2deg(a.path.keyframes[5, 5]) for a in kept])  # the held roll, degrees
    assert len(t["per_demo"]) == len(kept) and t["mean"] == pytest.approx(np.mean(t["per_demo"]))
    assert np.abs(np.asarray(t["per_demo"]) - drawn).max() <= TILT_TOLERANCE_DEG, (t, drawn)
    assert np.ptp(drawn) > 2 * TILT_TOLERANCE_DEG  # the rolls differ: matching each one means something
    assert math.isnan(demo_tilt(tmp_path / "none")["mean"])


def test_the_demonstrators_roll_option_reaches_the_recorded_joints(tmp_path, monkeypatch):
    """``generate(roll_deg=100)`` (``python -m sim.demos --roll 100``) drives the drawn paths, the
    IK and the saved joints: the recorded demonstration tilts 100 deg within the demonstrator's
    spread (the particle replay is skipped here: it judges the pour, not the roll)."""
    import sim.demos as D
    from sim.demo_paths import ROLL_SPREAD

    monkeypatch.setattr(D, "replay", lambda world, q, dt: (1.0, []))
    D.generate("powder", tmp_path, n=1, seed=4, progress=False, roll_deg=100.0)
    t = demo_tilt(tmp_path)
    assert len(t["per_demo"]) == 1
    assert abs(t["per_demo"][0] - 100.0) <= ROLL_SPREAD["powder"] + TILT_TOLERANCE_DEG, t
    assert json.loads((tmp_path / "ground_truth.json").read_text())["roll_deg"] == 100.0
