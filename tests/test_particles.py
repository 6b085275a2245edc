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


def _drop_into(body_xy_z, client) -> list[float]:
    """Heights (m) of particles dropped from 5 cm over points inside the bowl, after 1 s."""
    import pybullet as p

    r = L.PARTICLES["pour"][1]
    shape = p.createCollisionShape(p.GEOM_SPHERE, radius=r, physicsClientId=client)
    x0, y0, z0 = body_xy_z
    balls = [p.createMultiBody(L.PARTICLE_MASS, shape, -1, basePosition=(x0 + dx, y0 + dy, z0 + 0.05),
                               physicsClientId=client)
             for dx in (-0.06, 0.0, 0.06) for dy in (-0.06, 0.0, 0.06)]
    for _ in range(steps(1.0)):
        p.stepSimulation(physicsClientId=client)
    return [p.getBasePositionAndOrientation(b, physicsClientId=client)[0][2] - z0 for b in balls]


def test_bowl_floor_holds_particles_without_the_table():
    """The bowl's floor is its own: particles dropped into a bowl with nothing under it rest on
    its floor (PyBullet keeps at most 16 shapes per shape array and dropped the floor, the bowl's
    17th shape, so particles lay on the table and fell through where the bowl overhung its edge)."""
    import pybullet as p

    from sim import assets

    client = p.connect(p.DIRECT)
    try:
        p.setGravity(0, 0, -9.81, physicsClientId=client)
        p.setTimeStep(L.SIM_DT, physicsClientId=client)
        bowl = assets.build_bowl(client)
        p.resetBasePositionAndOrientation(bowl, (0.0, 0.0, 1.0), (0, 0, 0, 1), physicsClientId=client)
        heights = _drop_into((0.0, 0.0, 1.0), client)
        floor_top = L.BOWL_WALL
        assert min(heights) > floor_top, heights
        assert max(heights) < floor_top + 2 * L.PARTICLES["pour"][1] + 1e-3, heights
        shapes = L.BOWL_SEGMENTS + 1  # the wall's boxes and the floor disc
        assert shapes > assets.MAX_SHAPES_PER_ARRAY  # the case the split exists for
        assert p.getNumJoints(bowl, physicsClientId=client) == 1  # the floor, a fixed link
    finally:
        p.disconnect(client)


def test_compound_of_more_shapes_than_one_array_keeps_all():
    """Every shape of a body is built, however many: a particle rests on each of 20 boxes."""
    import pybullet as p

    from sim import assets

    client = p.connect(p.DIRECT)
    try:
        p.setGravity(0, 0, -9.81, physicsClientId=client)
        p.setTimeStep(L.SIM_DT, physicsClientId=client)
        ident = (0, 0, 0, 1)
        pads = [((0.1 * k, 0.0, 0.0), (0.02, 0.02, 0.005), ident) for k in range(20)]
        assets._compound(client, pads, (1, 1, 1, 1))
        shape = p.createCollisionShape(p.GEOM_SPHERE, radius=0.007, physicsClientId=client)
        balls = [p.createMultiBody(0.002, shape, -1, basePosition=(0.1 * k, 0.0, 0.05), physicsClientId=client)
                 for k in range(20)]
        for _ in range(steps(1.0)):
            p.stepSimulation(physicsClientId=client)
        z = np.array([p.getBasePositionAndOrientation(b, physicsClientId=client)[0][2] for b in balls])
        assert np.all(np.abs(z - 0.012) < 2e-3), z
        with pytest.raises(ValueError, match="at least one"):
            assets._compound(client, [], (1, 1, 1, 1))
    finally:
        p.disconnect(client)
