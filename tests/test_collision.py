"""Collision closures: obstacles, table, self collision, segments, restored simulator state."""

from __future__ import annotations

import numpy as np
import pybullet as p
import pytest

from sim import layout as L
from sim.collision import bisection_order, make_collision_fns


@pytest.fixture(scope="module")
def world(make_world):
    return make_world("powder")  # with particles in the spoon: they must not count as obstacles


@pytest.fixture(scope="module", params=["shadow", "inplace"])
def method(request):
    return request.param


@pytest.fixture(scope="module")
def fns(world, method):
    return make_collision_fns(world, method=method)


@pytest.fixture(scope="module")
def fns_no_obstacles(world, method):
    return make_collision_fns(world, obstacles=False, method=method)


@pytest.fixture
def roll_under_gripper(world):
    """The paper-towel roll placed right under the gripper at HOME_Q (its top reaches the hand)."""
    q_saved = world.get_q()
    world.set_q(L.HOME_Q)
    xy = world.T_world_gripper()[:2, 3]
    world.set_q(q_saved)
    world.place_object("paper_towels", xy)
    yield xy
    world.remove_object("paper_towels")


def snapshot_state(world):
    """Everything a check could disturb: all joint states, tool pose, particle poses."""
    c = world.client
    joints = p.getJointStates(world.robot, range(p.getNumJoints(world.robot, physicsClientId=c)),
                              physicsClientId=c)
    return ([(s[0], s[1]) for s in joints], world.T_world_tool().tolist(),
            [p.getBasePositionAndOrientation(b, physicsClientId=c) for b in world.particles.ids])


def test_home_is_free(fns):
    assert not fns.collision_fn(L.HOME_Q)


def test_arm_through_paper_towels_collides(fns, fns_no_obstacles, roll_under_gripper):
    assert fns.collision_fn(L.HOME_Q)
    assert not fns_no_obstacles.collision_fn(L.HOME_Q)


def test_segment_through_obstacle_rejected_though_ends_free(fns, fns_no_obstacles, roll_under_gripper):
    q1, q2 = L.HOME_Q.copy(), L.HOME_Q.copy()
    q1[0] -= 0.4  # swing the shoulder: the hand sweeps through the roll at the midpoint
    q2[0] += 0.4
    assert not fns.collision_fn(q1) and not fns.collision_fn(q2)
    assert fns.segment_fn(q1, q2)
    assert not fns_no_obstacles.segment_fn(q1, q2)
    assert not fns.segment_fn(q1, q1 + 0.5 * (L.HOME_Q - q1) * 0.5)  # a free part of it


def test_table_and_self_collision_without_obstacles(fns_no_obstacles):
    q_table = L.HOME_Q.copy()
    q_table[1] += 0.5  # lower the shoulder: the spoon goes into the table top
    assert fns_no_obstacles.collision_fn(q_table)
    q_self = np.array([-1.2, 0.2, 0.0, 1.4, 0.0, 1.5, 0.0])  # hand across the torso
    assert fns_no_obstacles.collision_fn(q_self)


def test_markers_and_particles_are_not_obstacles(world, fns):
    world.set_q(L.HOME_Q)
    world.move_object("marker_1", world.T_world_tool()[:3, 3])
    try:
        assert len(world.particles) > 0
        assert not fns.collision_fn(L.HOME_Q)
    finally:
        world.move_object("marker_1", L.DEFAULT_XY["marker_1"])


def test_joint_limits_checked_first(fns):
    q = L.HOME_Q.copy()
    q[3] = 3.0  # left_e1 upper limit is 2.618
    assert fns.collision_fn(q)
    assert fns.batch_collision_fn(q[None]).tolist() == [True]
    assert fns.segment_fn(L.HOME_Q, q)


def test_batch_equals_single(fns):
    rng = np.random.default_rng(0)
    Q = L.HOME_Q + rng.normal(0, 0.6, (40, 7))  # (40, 7), some outside the limits
    batch = fns.batch_collision_fn(Q)
    assert batch.shape == (40,) and batch.dtype == bool
    assert batch.tolist() == [fns.collision_fn(q) for q in Q]
    assert 0 < batch.sum() < 40


def test_hit_fn_names_what_each_configuration_hits(world, fns, roll_under_gripper):
    """``hit_fn`` agrees with the boolean checks and names what is hit: the roll under the
    gripper, the table, the robot itself, the joint limits; a named scene body is within the
    margin of the arm (exact distances in the world)."""
    from sim.collision import OBSTACLE_MARGIN

    q_table = L.HOME_Q.copy()
    q_table[1] += 0.5  # the spoon into the table top, away from the roll
    q_table[0] -= 0.6
    q_self = np.array([-1.2, 0.2, 0.0, 1.4, 0.0, 1.5, 0.0])  # hand across the torso
    q_limits = L.HOME_Q.copy()
    q_limits[3] = 3.0
    rng = np.random.default_rng(4)
    Q = np.concatenate([[L.HOME_Q, q_table, q_self, q_limits], L.HOME_Q + rng.normal(0, 0.3, (40, 7))])
    what = fns.hit_fn(Q)
    assert what.shape == (len(Q),)
    assert (what != "").tolist() == [fns.collision_fn(q) for q in Q]  # the single check: another path
    assert what[:4].tolist() == ["paper_towels", "table", "self", "limits"]
    bodies = {"table": world.table, **{n: b for n, b in world.objects.items()
                                       if world.object_kind(n) in ("container", "obstacle", "item")}}
    assert set(what.tolist()) <= set(bodies) | {"", "self", "limits"}
    arm = {i for n, i in world.link_index.items() if n.startswith(("left_", "l_gripper")) or n == "tool"} - {-1}
    c, q_saved = world.client, world.get_q()
    try:
        for q, w in zip(Q, what.tolist()):
            if w in bodies:
                world.set_q(q)
                pts = p.getClosestPoints(world.robot, bodies[w], 0.05, physicsClientId=c)
                assert min(pt[8] for pt in pts if pt[3] in arm) < OBSTACLE_MARGIN
    finally:
        world.set_q(q_saved)


def test_state_unchanged_after_checks(world, fns, roll_under_gripper):
    q_other = L.HOME_Q + 0.05
    world.set_q(q_other)
    before = snapshot_state(world)
    fns.collision_fn(L.HOME_Q)                       # in collision (the roll)
    fns.collision_fn(q_other - 0.1)
    fns.batch_collision_fn(np.stack([L.HOME_Q, q_other, q_other - 0.3]))
    q1, q2 = L.HOME_Q.copy(), L.HOME_Q.copy()
    q1[0] -= 0.4
    q2[0] += 0.4
    fns.segment_fn(q1, q2)
    assert snapshot_state(world) == before
    world.set_q(L.HOME_Q)


def test_bisection_order_and_bad_input(world, fns):
    assert bisection_order(4) == [0, 4, 2, 1, 3]
    assert sorted(bisection_order(9)) == list(range(10))
    with pytest.raises(ValueError, match=r"q must have shape \(7,\), got \(6,\)"):
        fns.collision_fn(np.zeros(6))
    with pytest.raises(ValueError, match=r"Q must have shape \(B, 7\)"):
        fns.batch_collision_fn(np.zeros(7))
    with pytest.raises(ValueError, match="resolution must be > 0"):
        make_collision_fns(world, resolution=0.0)
    with pytest.raises(ValueError, match="method must be"):
        make_collision_fns(world, method="fast")


def test_methods_agree(world):
    shadow, inplace = make_collision_fns(world), make_collision_fns(world, method="inplace")
    world.place_object("vase", (0.75, 0.6))
    try:
        rng = np.random.default_rng(3)
        Q = L.HOME_Q + rng.normal(0, 0.5, (150, 7))  # (150, 7): near home, where the obstacles are
        a, b = shadow.batch_collision_fn(Q), inplace.batch_collision_fn(Q)
        assert 0 < a.sum() < len(Q)
        assert (a == b).all()
    finally:
        world.remove_object("vase")
        shadow.close()


def test_every_configuration_closer_than_the_margin_collides(world, fns, fns_no_obstacles, roll_under_gripper):
    """The margin holds for every shape pair, and no more than the margin is kept: among the
    configurations free of self collision, those whose exact clearance to the scene
    (getClosestPoints in the world, over the arm, fingers and tool) is below OBSTACLE_MARGIN are
    in collision, those clear of it by a millimetre are free. (Bullet's contact points missed a
    finger box 0.9 mm from the roll's cylinder.)"""
    from sim.collision import OBSTACLE_MARGIN

    c = world.client
    arm = {i for n, i in world.link_index.items() if n.startswith(("left_", "l_gripper")) or n == "tool"} - {-1}
    scene = [world.table] + [b for n, b in world.objects.items()
                             if world.object_kind(n) in ("container", "obstacle", "item")]
    assert world.objects["paper_towels"] in scene
    rng = np.random.default_rng(5)
    Q = L.HOME_Q + rng.normal(0, 0.25, (160, 7))  # (160, 7): around the roll under the gripper
    q_saved = world.get_q()
    clearance = []
    for q in Q:
        world.set_q(q)
        clearance.append(min([pt[8] for b in scene for pt in p.getClosestPoints(world.robot, b, 0.05, physicsClientId=c)
                              if pt[3] in arm] or [0.05]))
    world.set_q(q_saved)
    clearance = np.asarray(clearance)
    close = (clearance < OBSTACLE_MARGIN) & (clearance > 0)  # near, not penetrating: where contacts failed
    assert close.sum() >= 5, "the sample must hold configurations within the margin"
    verdict = fns.batch_collision_fn(Q)
    assert verdict[close].all(), f"{(~verdict[close]).sum()} of {close.sum()} called free"
    # without obstacles only self collision, limits and the table count; clear ones keep 16 mm from the table
    clear = (clearance > OBSTACLE_MARGIN + 1e-3) & ~fns_no_obstacles.batch_collision_fn(Q)
    assert clear.sum() >= 5
    assert not verdict[clear].any(), f"{verdict[clear].sum()} of {clear.sum()} clear of the margin called in collision"


def test_joint_levers_bound_how_far_any_arm_point_moves(world):
    """``sum_j lever_j |dq_j|`` bounds the motion of every link origin after the joints (and of
    the tool's far end), measured with PyBullet's own link poses on random small moves."""
    from sim.arm_geometry import joint_levers
    levers = joint_levers(world)
    assert levers.shape == (7,) and np.all(np.diff(levers) < 0) and levers[-1] > 0.15
    rng = np.random.default_rng(0)
    c = world.client
    far = np.array([0.0, 0.0, L.SPOON_SCOOP_Z[1]])  # the spoon's tip, gripper frame
    links = [l for l in range(p.getNumJoints(world.robot, physicsClientId=c)) if l > world.arm_joints[0]]

    def points(q):
        world.set_q(q)
        pts = [np.asarray(p.getLinkState(world.robot, l, physicsClientId=c)[4]) for l in links]
        T = world.T_world_gripper()
        return np.array(pts + [T[:3, :3] @ far + T[:3, 3]])

    try:
        for _ in range(20):
            q = L.HOME_Q + rng.uniform(-0.5, 0.5, 7)
            dq = rng.uniform(-0.2, 0.2, 7)
            moved = np.linalg.norm(points(q + dq) - points(q), axis=1).max()
            assert moved <= levers @ np.abs(dq) + 1e-9
    finally:
        world.set_q(L.HOME_Q)


def test_segments_are_checked_finely_enough_for_the_margin(world):
    """A segment is split so that the arm moves at most ``max_travel`` between checks: a shoulder
    swing of 0.19 rad (about 0.3 m at the tool) is checked at least 10 times, not 4."""
    calls = []
    fns = make_collision_fns(world, obstacles=False)
    coarse = make_collision_fns(world, obstacles=False, max_travel=None)
    q1 = L.HOME_Q.copy()
    q2 = q1.copy()
    q2[0] += 0.19
    import sim.collision as C
    real = C.bisection_order
    try:
        C.bisection_order = lambda n: calls.append(n) or real(n)
        assert not fns.segment_fn(q1, q2) and not coarse.segment_fn(q1, q2)
    finally:
        C.bisection_order = real
    assert calls[1] == 4 and calls[0] >= 10
    with pytest.raises(ValueError, match="max_travel"):
        make_collision_fns(world, max_travel=0.0)


def test_batched_boxes_hold_pybullets_and_give_the_same_answers(world, roll_under_gripper):
    """``sim.link_boxes``: the moving links' boxes computed for a batch from the forward
    kinematics contain PyBullet's ``getAABB`` boxes in every configuration, and a batch large enough
    to use them (``MIN_BATCH``) names exactly what the configurations checked one by one (PyBullet's
    boxes) name, the same first hit among several bodies included."""
    from lfd.robot.kinematics import KinematicModel
    from sim.arm_geometry import self_pairs
    from sim.link_boxes import MIN_BATCH, LinkBoxes

    c, robot = world.client, world.robot
    moving, _, _ = self_pairs(c, robot, world.arm_joints)
    boxes = LinkBoxes(c, robot, world.arm_joints, moving, KinematicModel.from_spec(world.spec))
    rng = np.random.default_rng(8)
    Q = L.HOME_Q + rng.normal(0, 0.8, (30, 7))  # (30, 7)
    B = boxes(Q)                                 # (30, M, 2, 3)
    q_saved = world.get_q()
    try:
        for q, b in zip(Q, B):
            world.set_q(q)
            exact = np.array([p.getAABB(robot, k, physicsClientId=c) for k in moving])  # (M, 2, 3)
            assert (b[:, 0] <= exact[:, 0]).all() and (b[:, 1] >= exact[:, 1]).all()
            assert np.abs(b - exact).max() < 0.15  # and not so loose that every pair is measured
    finally:
        world.set_q(q_saved)

    fns = make_collision_fns(world)
    world.place_object("vase", (0.75, 0.6))
    try:
        Q = L.HOME_Q + rng.normal(0, 0.3, (4 * MIN_BATCH, 7))  # around the roll, the vase and the table
        batch = fns.hit_fn(Q)
        assert batch.tolist() == [fns.hit_fn(q[None])[0] for q in Q]
        assert {"", "paper_towels", "table"} <= set(batch.tolist())
    finally:
        world.remove_object("vase")
        fns.close()


def test_batched_boxes_refuse_another_robots_kinematics(world):
    """A kinematic model of another URDF than the world's robot is refused at set-up, not used."""
    from lfd.robot.kinematics import KinematicModel
    from lfd.robot.robots import PANDA
    from sim.arm_geometry import self_pairs
    from sim.link_boxes import LinkBoxes

    moving, _, _ = self_pairs(world.client, world.robot, world.arm_joints)
    q_saved = world.get_q()
    with pytest.raises(RuntimeError, match="disagree about where it is"):
        LinkBoxes(world.client, world.robot, world.arm_joints, moving, KinematicModel.from_spec(PANDA))
    assert np.allclose(world.get_q(), q_saved)  # the arm put back
