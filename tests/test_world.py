"""The simulated lab: robot placement, tool frame, landmarks, objects, rendering, CLI errors."""

from __future__ import annotations


import numpy as np
import pybullet as p
import pytest

from lfd.robot.robots import BAXTER_LEFT, RobotSpec
from lfd.learning.tasks import POUR, POWDER
from sim import layout as L
from sim.world import World
from helpers import entry_point, run_cli


@pytest.fixture(scope="module")
def world(make_world):
    return make_world("powder", n_particles=0)


def test_robot_at_origin_with_fixed_base(world):
    pos, quat = p.getBasePositionAndOrientation(world.robot, physicsClientId=world.client)
    assert np.allclose(pos, 0) and np.allclose(quat, (0, 0, 0, 1))
    assert p.getDynamicsInfo(world.robot, -1, physicsClientId=world.client)[0] == 0.0  # fixed


def test_tool_frame_is_gripper_frame_and_level_at_home(world):
    world.set_q(L.HOME_Q)
    np.testing.assert_allclose(world.T_world_tool(), world.T_world_gripper(), atol=1e-6)
    assert world.T_world_tool()[2, 1] > 0.99          # the tool's up (gripper +y) is world up
    assert world.T_world_tool()[2, 3] > L.TABLE_TOP_Z + L.SOURCE_HEIGHT


def test_every_joint_within_its_limits_and_still_there_after_motion(world):
    """Joints the arm does not command (fingers, head, right arm) start inside their URDF limits
    and stay put while the arm moves: the collision checker's copy of the robot assumes so (a
    finger reset outside its range slid 1 cm under physics and touched obstacles unchecked)."""
    c = world.client
    movable = [j for j in range(p.getNumJoints(world.robot, physicsClientId=c))
               if p.getJointInfo(world.robot, j, physicsClientId=c)[2] in (p.JOINT_REVOLUTE, p.JOINT_PRISMATIC)
               and j not in world.arm_joints]
    before = {}
    for j in movable:
        lo, hi = p.getJointInfo(world.robot, j, physicsClientId=c)[8:10]
        before[j] = p.getJointState(world.robot, j, physicsClientId=c)[0]
        if hi > lo:
            assert lo - 1e-9 <= before[j] <= hi + 1e-9, p.getJointInfo(world.robot, j, physicsClientId=c)[1]
    world.set_q(L.HOME_Q)
    for k in range(240):
        q = L.HOME_Q.copy()
        q[0] += 0.4 * (k + 1) / 240
        q[6] += 0.8 * (k + 1) / 240
        world.command_q(q)
        world.step()
    for j in movable:
        assert abs(p.getJointState(world.robot, j, physicsClientId=c)[0] - before[j]) < 1e-3
    world.set_q(L.HOME_Q)


def test_manual_tool_points_match_tool_geometry():
    assert POWDER.manual_tool_point == L.SPOON_TIP
    assert POUR.manual_tool_point == L.PITCHER_SPOUT_LIP


def test_sensed_landmarks_powder(world):
    names, T = world.sensed_landmarks()
    assert names == ("bowl", "marker_1", "marker_2", "marker_3", "marker_4")
    assert T.shape == (5, 4, 4)
    np.testing.assert_allclose(T[:, :3, :3], np.tile(np.eye(3), (5, 1, 1)))
    bowl = world.object_pose("bowl")[:3, 3]
    np.testing.assert_allclose(T[0, :3, 3], bowl + (0, 0, L.BOWL_HEIGHT / 2))
    np.testing.assert_allclose(bowl, (*L.BOWL_DEFAULT_XY, L.TABLE_TOP_Z))


def test_sensed_landmarks_follow_moved_bowl(world):
    world.move_object("bowl", (0.9, 0.2))
    try:
        _, T = world.sensed_landmarks()
        np.testing.assert_allclose(T[0, :3, 3], (0.9, 0.2, L.TABLE_TOP_Z + L.BOWL_HEIGHT / 2))
    finally:
        world.move_object("bowl", L.BOWL_DEFAULT_XY)


def test_markers_are_visual_only(world):
    body = world.objects["marker_1"]
    assert p.getCollisionShapeData(body, -1, physicsClientId=world.client) == ()


def test_obstacles_placed_moved_removed(world):
    assert "paper_towels" not in world.objects  # demonstrations: no obstacles
    world.place_object("lamp_shade", (0.8, 0.4))
    world.place_object("books", (1.1, 0.6, L.TABLE_TOP_Z))
    assert world.object_pose("lamp_shade")[2, 3] == pytest.approx(L.TABLE_TOP_Z + L.LAMP_BOTTOM_ABOVE_TABLE)
    world.move_object("lamp_shade", (0.7, 0.3))
    assert world.object_pose("lamp_shade")[0, 3] == pytest.approx(0.7)
    world.remove_object("lamp_shade")
    world.remove_object("books")
    assert "lamp_shade" not in world.objects and "books" not in world.objects
    with pytest.raises(ValueError, match="unknown object 'sofa'"):
        world.place_object("sofa", (0, 0))
    with pytest.raises(ValueError, match="'vase' is not in the scene"):
        world.move_object("vase", (0, 0))
    with pytest.raises(ValueError, match=r"where must be .* got shape \(4,\)"):
        world.move_object("bowl", (0, 0, 0, 0))


def test_pour_scene_landmarks_and_scenario():
    with World("pour", n_particles=0, scenario={"lamp_shade": (0.8, 0.4), "bowl": (0.7, 0.2)}) as w:
        names, T = w.sensed_landmarks()
        assert names == ("bowl", "scissors", "spoon", "vase", "paper_towels")
        assert T.shape == (5, 4, 4)
        np.testing.assert_allclose(T[0, :2, 3], (0.7, 0.2))
        assert w.object_kind("lamp_shade") == "obstacle"


def test_render_and_snapshot(world, tmp_path):
    img = world.render(64, 48)
    assert img.shape == (48, 64, 3) and img.dtype == np.uint8
    assert img.std() > 5  # not a blank image
    out = world.snapshot(tmp_path / "scene.png", 64, 48)
    assert out.stat().st_size > 100


def test_bad_world_arguments():
    with pytest.raises(ValueError, match="task must be one of"):
        World("soup")
    spec = RobotSpec("ghost", "/nonexistent/robot.urdf", "left_gripper", BAXTER_LEFT.joint_names)
    with pytest.raises(FileNotFoundError, match="URDF file not found"):
        World("powder", robot=spec)


@pytest.mark.parametrize("args, message", [
    (["--task", "soup"], "--task must be one of"),
    (["--snapshot", "/nonexistent/dir/scene.png"], "does not exist"),
    (["--snapshot", "scene.jpg"], "must name a .png"),
    (["--steps", "x"], "argument --steps: invalid int value: 'x'"),  # argparse's error: one line too
])
def test_cli_bad_input_exits_2_with_one_line(args, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a relative --snapshot would be written here
    r = run_cli(*entry_point("python -m sim.world"), args, capsys)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in r.stderr


def test_contact_log_counts_touches_not_close_passes(world):
    """PyBullet reports contact points up to 2 cm before bodies meet; the executor's log counts
    only points at most 1 mm apart."""
    from sim.judge import TOUCH_DISTANCE, ContactLog
    world.set_q(L.HOME_Q)
    xy = world.T_world_gripper()[:2, 3]
    c = world.client

    def gap(dx):
        world.place_object("paper_towels", (xy[0] + dx, xy[1]))
        pts = p.getClosestPoints(world.robot, world.objects["paper_towels"], 0.05, physicsClientId=c)
        return min((pt[8] for pt in pts), default=np.inf)

    try:
        dxs = np.linspace(0.0, 0.4, 401)
        gaps = np.array([gap(dx) for dx in dxs])
        near = dxs[np.flatnonzero((gaps > 0.004) & (gaps < 0.015))[0]]
        for dx, touching in ((near, False), (0.0, True)):
            g = gap(dx)
            log = ContactLog(world)
            world.command_q(L.HOME_Q)
            world.step(1)
            log.poll(0.0)
            hit = any(e["body"] == "paper_towels" for e in log.events)
            assert hit == touching, (dx, g, log.events)
            assert all(e["distance_m"] <= TOUCH_DISTANCE for e in log.events)
    finally:
        world.remove_object("paper_towels")
        world.set_q(L.HOME_Q)


@pytest.mark.parametrize("stop", [ValueError, KeyboardInterrupt])
def test_a_world_whose_construction_fails_leaves_no_client_connected(monkeypatch, stop):
    """A failure (or Ctrl-C) while the scene is built disconnects the world's client, and a
    collision checker whose private client fails to set up disconnects that one."""
    import sim.collision
    import sim.world

    opened = []
    connect = p.connect
    monkeypatch.setattr(sim.world.p, "connect", lambda *a, **kw: opened.append(connect(*a, **kw)) or opened[-1])

    def broken(*args, **kwargs):
        raise stop("while building")

    with monkeypatch.context() as m:
        m.setattr(World, "_build", broken)
        with pytest.raises(stop):
            World("powder")
    assert len(opened) == 1 and not p.isConnected(opened[0])
    with World("powder") as w:
        with monkeypatch.context() as m:
            m.setattr(sim.collision, "_shadow_robot", broken)
            with pytest.raises(stop):
                sim.collision.make_collision_fns(w)
        assert len(opened) == 3 and not p.isConnected(opened[2]) and p.isConnected(w.client)
