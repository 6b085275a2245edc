"""Particles held by the tools under physics: kept while level, lost when tilted past 90 deg."""

from __future__ import annotations

import numpy as np
import pytest

from sim import layout as L
from sim.particles import cavity_points

SECONDS = 3.0


@pytest.fixture(scope="module", params=["powder", "pour"])
def world(request, make_world):
    return make_world(request.param)


def steps(seconds: float) -> int:
    return int(round(seconds / L.SIM_DT))


def tilt_q(degrees: float) -> np.ndarray:
    """HOME_Q with the wrist rolled (about the gripper z axis) by ``degrees``."""
    q = L.HOME_Q.copy()
    q[6] += np.deg2rad(degrees)
    return q


def roll_wrist(world, degrees: float, seconds: float) -> None:
    """Drive the wrist roll (about the gripper z axis) from HOME_Q by ``degrees`` under physics."""
    n = steps(seconds)
    for k in range(n):
        world.command_q(tilt_q(degrees * (k + 1) / n))
        world.step()


def test_tool_is_level_at_home(world):
    world.set_q(L.HOME_Q)
    up = world.T_world_tool()[:3, 1]  # the tool's "up" is the gripper's +y
    assert up @ np.array([0.0, 0.0, 1.0]) > 0.99


def test_level_tool_keeps_particles(world):
    world.set_q(L.HOME_Q)
    world.respawn_particles()
    world.step(steps(SECONDS))
    assert world.fraction_in_tool() >= 0.9
    assert np.allclose(world.get_q(), L.HOME_Q, atol=1e-3)  # the arm held still under physics


def test_tilting_past_90_degrees_empties_the_tool(world):
    world.set_q(L.HOME_Q)
    world.respawn_particles()
    world.step(steps(0.5))
    roll_wrist(world, 120, seconds=1.0)
    world.step(steps(1.0))
    up = world.T_world_tool()[:3, 1]
    assert up[2] < 0.0  # past 90 deg
    assert world.fraction_in_tool() <= 0.3
    assert world.fraction_spilled() >= 0.7
    world.set_q(L.HOME_Q)


def test_bad_particle_arguments():
    with pytest.raises(ValueError, match="n_particles must be >= 0"):
        cavity_points("powder", -1, 0.005)
    with pytest.raises(ValueError, match="particle_radius must be in"):
        cavity_points("pour", 10, 0.5)
    with pytest.raises(ValueError, match="do not fit"):
        cavity_points("powder", 10_000, 0.005)
    with pytest.raises(ValueError, match="task must be"):
        cavity_points("soup", 10, 0.005)


def test_dumping_over_the_bowl_fills_it(world):
    """The bowl moved under the rim the tilted tool pours over catches what it drops."""
    # rolling about +z lowers the tool's -x side: the spoon's rim there, the pitcher's spout lip
    lip = {"powder": (-L.SPOON_RIM_HALF_X, L.SPOON_WALL_HEIGHT, np.mean(L.SPOON_SCOOP_Z)),
           "pour": L.PITCHER_SPOUT_LIP}[world.task]
    # the liquid runs off the spout while the roll passes 90 deg; the powder falls at the end
    world.set_q(tilt_q({"powder": 120, "pour": 90}[world.task]))
    T = world.T_world_tool()
    xy = (T[:3, :3] @ np.array(lip) + T[:3, 3])[:2]
    world.set_q(L.HOME_Q)
    world.move_object("source", (xy[0], xy[1] + 0.5))
    world.move_object("bowl", xy)
    try:
        world.respawn_particles()
        world.step(steps(0.5))
        roll_wrist(world, 120, seconds=1.0)
        world.step(steps(1.0))
        assert world.fraction_in_bowl() >= 0.7
    finally:
        world.move_object("bowl", L.BOWL_DEFAULT_XY)
        world.move_object("source", L.SOURCE_DEFAULT_XY)
        world.set_q(L.HOME_Q)
