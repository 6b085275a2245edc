"""Collision checking of the left arm (with its tool) for the planners.

``make_collision_fns(world)`` does the setup once -- which links move, which link pairs can
collide, which bodies are obstacles -- and returns closures:

* ``collision_fn(q (7,)) -> bool``: joint limits first, then self collision (the arm and tool
  against the robot's other links and against non-adjacent arm links), the table and the
  obstacles;
* ``batch_collision_fn(Q (B, 7)) -> (B,) bool``;
* ``hit_fn(Q (B, 7)) -> (B,) str``: what each configuration hits, ``""`` where free: ``"limits"``,
  ``"self"``, ``"table"`` or a scene object's name (the first found), the planner's
  ``batch_collision_fn`` (``lfd.planning.roadmap.Roadmap.hits``: an object that moves away then
  frees only the edges it blocked);
* ``segment_fn(q1, q2) -> bool``: the straight joint-space segment, interpolated so that no
  joint moves more than ``resolution`` rad and no point of the arm or tool moves more than
  ``max_travel`` (default ``2 * (OBSTACLE_MARGIN - TRACKING_ALLOWANCE)``) between checked configurations, checked in
  bisection order (ends, middle, quarters, ...), so that a collision is usually found early.
  The travel is estimated from each joint's lever (the summed lengths of the links after it
  plus the tool's reach) as ``|| lever * dq ||_2``: the strict bound ``sum_j lever_j |dq_j|``
  would check a typical roadmap edge ~90 times; the 2-norm is exact for one joint and a fair
  estimate when several move. Between two configurations checked ``OBSTACLE_MARGIN`` clear of
  the scene a point moving ``2 * (OBSTACLE_MARGIN - TRACKING_ALLOWANCE)`` stays
  ``TRACKING_ALLOWANCE`` clear, more than the executor's measured tracking error. (A plain 0.05 rad step moves
  the gripper up to 5 cm per shoulder joint: executed paths passed within a millimetre of
  obstacles although every checked configuration kept 1.5 cm.)

True means *in collision*. Particles and visual-only landmark markers are never obstacles.
Scene objects are looked up at call time (``world.scene_version``), so objects moved, placed
or removed after ``make_collision_fns`` are honoured.

Two interchangeable checkers (``method``), same answers, measured on 1,000 uniform random
configurations (``benchmarks/collision.py``):

* ``"shadow"`` (default, faster): a private DIRECT client holds a collision-only copy
  of the robot (self collision enabled for exactly the checked pairs, via collision filter
  pairs), the table and copies of the obstacles; one ``performCollisionDetection`` per
  configuration for self collision (``getContactPoints``). The world's client is only read,
  never written: its joints, tool and particles are untouched by construction. The rest of the
  robot (right arm, head, fingers) is copied once, at setup. A batch of ``MIN_BATCH`` or more
  configurations (``hit_fn``, the planner's checks) takes the moving links' boxes from one
  forward pass (``sim.link_boxes``) instead of 16 ``getAABB`` calls per configuration.
* ``"inplace"``: in the world's own client, an AABB prefilter per link pair, then
  ``getClosestPoints(distance=0)`` on the overlapping pairs; a context manager restores the
  arm's joint positions and velocities after every call.

Both measure the scene the same way (``_too_close``): exact distances (``getClosestPoints``)
of the moving links to the table and obstacles whose bounding boxes come within
``OBSTACLE_MARGIN`` (the batched boxes contain PyBullet's: a few more pairs measured, the same
answers); a configuration closer than that is in collision. Self collision is a
touch (distance < 0).

"Adjacent" pairs are excluded: links whose path in the kinematic tree crosses at most one arm
joint (e.g. an upper shoulder and the torso, the tool and the gripper), plus the pairs in
``sim.arm_geometry.ALWAYS_TOUCHING`` (Baxter's collision shapes overlap there at almost every configuration).
"""

from __future__ import annotations

import contextlib
import math
import re
import tempfile
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim.arm_geometry import joint_levers, self_pairs
from sim.bullet import p

__all__ = ["CollisionFns", "bisection_order", "make_collision_fns"]

# The arm and the tool keep this clearance (m) from the table and the obstacles (exact distances,
# ``_too_close``).
OBSTACLE_MARGIN = 0.015
# How far (m) the executed arm may be from where it is commanded: PyBullet's position control
# lags the minimum-jerk profile by at most 3.6 mm at any arm frame or the tool point (measured:
# ``RunResult.tracking_max_mm``, 50 powder scenes of base seeds 0 and 1 with the world running on). Between
# two checked configurations a point moves at most ``2 * (OBSTACLE_MARGIN - TRACKING_ALLOWANCE)``,
# so the commanded arm keeps ``TRACKING_ALLOWANCE`` from the scene and the executed one touches
# nothing.
TRACKING_ALLOWANCE = 0.005

_OBSTACLE_KINDS = ("container", "obstacle", "item")


@dataclass(frozen=True)
class CollisionFns:
    """The collision closures of one world (see the module docstring).

    ``self_pairs``: the checked (moving link, robot link) index pairs; ``resolution``: the
    largest joint step (rad) between configurations checked along a segment; ``close()``
    releases the shadow client (also done when the closures are garbage collected or the
    world is closed).
    """

    collision_fn: Callable[[np.ndarray], bool]
    batch_collision_fn: Callable[[np.ndarray], np.ndarray]
    segment_fn: Callable[[np.ndarray, np.ndarray], bool]
    hit_fn: Callable[[np.ndarray], np.ndarray]
    resolution: float
    obstacles: bool
    method: str
    self_pairs: tuple = field(repr=False, default=())
    close: Callable[[], None] = field(repr=False, default=lambda: None)


def bisection_order(n: int) -> list[int]:
    """Indices ``0..n`` ordered ends first, then midpoints breadth-first."""
    if n <= 0:
        return [0]
    order, queue = [0, n], [(0, n)]
    while queue:
        nxt = []
        for a, b in queue:
            if b - a > 1:
                m = (a + b) // 2
                order.append(m)
                nxt.extend([(a, m), (m, b)])
        queue = nxt
    return order


def _obstacle_names(world, obstacles, ignore):
    if not obstacles:
        return []
    return [n for n in world.objects if n not in ignore and world.object_kind(n) in _OBSTACLE_KINDS]


def _overlap(a: np.ndarray, b: np.ndarray, pad: float = 0.0) -> np.ndarray:
    """Whether boxes ``a (..., 2, 3)`` and ``b (..., 2, 3)`` (min, max corners; broadcast) come
    within ``pad`` of each other: ``(...)`` bool."""
    return ((a[..., 0, :] - pad <= b[..., 1, :]) & (b[..., 0, :] <= a[..., 1, :] + pad)).all(axis=-1)


def _near(link_boxes: np.ndarray, body_boxes: np.ndarray) -> np.ndarray:
    """Which (moving link, scene body) pairs have boxes within ``OBSTACLE_MARGIN``: ``link_boxes
    (..., M, 2, 3)``, ``body_boxes (E, 2, 3)`` -> ``(..., M, E)`` bool."""
    return _overlap(link_boxes[..., :, None, :, :], body_boxes, OBSTACLE_MARGIN)


def _too_close(client, robot, moving, bodies, near) -> int:
    """The first scene body (its index, -1 for none) a moving link comes within
    ``OBSTACLE_MARGIN`` of: exact distances (``getClosestPoints``) for the (link, body) pairs
    ``near (M, E)`` whose boxes are that close (``_near``), link by link; ``bodies (E,)``. (Contact points from
    ``performCollisionDetection`` are no substitute: Bullet reports positive-distance points for
    some shape pairs only, e.g. not for a finger's box 0.9 mm from a cylinder, which a run then
    touched.)"""
    for i, e in zip(*np.nonzero(near)):
        pts = p.getClosestPoints(robot, bodies[e], OBSTACLE_MARGIN, moving[i], -1, physicsClientId=client)
        if any(pt[8] < OBSTACLE_MARGIN for pt in pts):
            return int(e)
    return -1


def _inplace_checker(world, joints, moving, fixed, pairs, obstacles, ignore):
    """``(check_here(q), restored, close, near_fn)`` working in the world's own client; its
    ``near_fn`` gives None: PyBullet's boxes are read per configuration."""
    client, robot = world.client, world.robot
    all_links = moving + fixed
    pair_a = np.array([moving.index(a) for a, _ in pairs])
    pair_b = np.array([all_links.index(b) for _, b in pairs])
    fixed_aabbs = np.array([p.getAABB(robot, k, physicsClientId=client) for k in fixed]).reshape(-1, 2, 3)
    cache = {"version": None}

    def env_boxes():
        """Obstacle bodies ``(E,)`` and their AABBs ``(E, 2, 3)``, cached per scene version."""
        if cache["version"] != world.scene_version:
            names = ["table"] + _obstacle_names(world, obstacles, ignore)
            bodies = [world.table] + [world.objects[n] for n in names[1:]]
            cache.update(version=world.scene_version, bodies=bodies, names=names,
                         aabbs=np.array([p.getAABB(b, -1, physicsClientId=client) for b in bodies]))
        return cache["bodies"], cache["aabbs"], cache["names"]

    @contextlib.contextmanager
    def restored():
        saved = p.getJointStates(robot, joints, physicsClientId=client)
        try:
            yield
        finally:
            p.resetJointStatesMultiDof(robot, joints, [[s[0]] for s in saved],
                                       targetVelocities=[[s[1]] for s in saved], physicsClientId=client)

    def hits(link_a, link_b) -> bool:
        pts = p.getClosestPoints(robot, robot, 0.0, link_a, link_b, physicsClientId=client)
        return any(pt[8] < 0.0 for pt in pts)

    def check_here(q) -> str:
        # one call for all joints: a single forward-kinematics update (7x faster than a loop)
        p.resetJointStatesMultiDof(robot, joints, [[v] for v in q.tolist()], physicsClientId=client)
        moving_aabbs = np.array([p.getAABB(robot, k, physicsClientId=client) for k in moving])  # (M, 2, 3)
        boxes = np.concatenate([moving_aabbs, fixed_aabbs])                                     # (M+S, 2, 3)
        A, B = moving_aabbs[pair_a], boxes[pair_b]                                              # (P, 2, 3)
        for k in np.flatnonzero(_overlap(A, B)):
            if hits(pairs[k][0], pairs[k][1]):
                return "self"
        bodies, env, names = env_boxes()
        e = _too_close(client, robot, moving, bodies, _near(moving_aabbs, env))
        return names[e] if e >= 0 else ""

    return check_here, restored, lambda: None, lambda Q: None


def _scene_body(shadow: int, body: int) -> int:
    """``body`` of the private client taken out of performCollisionDetection (self collision
    only); ``_too_close`` measures the scene. getClosestPoints ignores collision filters (PyBullet
    3.2.x; bullet3 issue 4376 calls it a bug): should a release change that,
    test_every_configuration_closer_than_the_margin_collides fails, and this filter must go."""
    for link in range(-1, p.getNumJoints(body, physicsClientId=shadow)):
        p.setCollisionFilterGroupMask(body, link, 0, 0, physicsClientId=shadow)
    return body


def _shadow_robot(world, shadow: int, shaped, pairs) -> int:
    """The world's robot loaded into the private client ``shadow`` without its visuals, in the
    world's joint state, self collision kept only between the link pairs of ``pairs``."""
    from sim import quiet_stdio
    from sim.world import patched_urdf

    with tempfile.TemporaryDirectory() as tmp:
        urdf = patched_urdf(world.spec, world.task, Path(tmp))
        urdf.write_text(re.sub(r"<visual>.*?</visual>", "", urdf.read_text(), flags=re.DOTALL))
        with quiet_stdio():
            robot = p.loadURDF(str(urdf), (0, 0, 0), (0, 0, 0, 1), useFixedBase=True,
                               flags=p.URDF_USE_SELF_COLLISION, physicsClientId=shadow)
    for j in range(p.getNumJoints(robot, physicsClientId=shadow)):  # right arm, head, fingers as in the world
        p.resetJointState(robot, j, p.getJointState(world.robot, j, physicsClientId=world.client)[0],
                          physicsClientId=shadow)
    checked = {frozenset(pr) for pr in pairs}
    for i, a in enumerate(shaped):
        for b in shaped[i + 1:]:
            if frozenset((a, b)) not in checked:
                p.setCollisionFilterPair(robot, robot, a, b, 0, physicsClientId=shadow)
    return robot


def _shadow_checker(world, joints, moving, fixed, pairs, obstacles, ignore):
    """``(check_here(q, near=None), restored, close, near_fn)`` working in a private
    collision-only client; ``near_fn(Q (B, d)) -> (B, M, E)``, the (link, scene body) pairs to
    measure for a batch (``sim.link_boxes``), or None for a batch too small to gain from it."""
    from lfd.robot.kinematics import KinematicModel
    from sim import assets
    from sim.link_boxes import MIN_BATCH, LinkBoxes

    shadow = p.connect(p.DIRECT)
    if shadow < 0:
        raise RuntimeError("cannot connect a PyBullet client for the collision checks")
    try:
        robot = _shadow_robot(world, shadow, moving + fixed, pairs)
        bodies = {"table": _scene_body(shadow, assets.build_table(shadow))}
        link_boxes = LinkBoxes(shadow, robot, joints, moving, KinematicModel.from_spec(world.spec))
    except BaseException:  # no private client is left connected when its set-up fails
        p.disconnect(shadow)
        raise
    moving_set = frozenset(moving)
    cache = {"version": None}

    def sync():
        if cache["version"] == world.scene_version:
            return
        wanted = _obstacle_names(world, obstacles, ignore)
        for name in [b for b in bodies if b != "table" and b not in wanted]:
            p.removeBody(bodies.pop(name), physicsClientId=shadow)
        for name in wanted:
            if name not in bodies:
                bodies[name] = _scene_body(shadow, assets.BUILDERS[name][0](shadow))
            pos, quat = p.getBasePositionAndOrientation(world.objects[name], physicsClientId=world.client)
            p.resetBasePositionAndOrientation(bodies[name], pos, quat, physicsClientId=shadow)
        cache.update(version=world.scene_version, bodies=list(bodies.values()), names=list(bodies),
                     boxes=np.array([p.getAABB(b, -1, physicsClientId=shadow) for b in bodies.values()]))

    def near_fn(Q):
        if len(Q) < MIN_BATCH:
            return None
        sync()
        return _near(link_boxes(Q), cache["boxes"])  # (B, M, E)

    def check_here(q, near=None) -> str:
        sync()
        p.resetJointStatesMultiDof(robot, joints, [[v] for v in q.tolist()], physicsClientId=shadow)
        p.performCollisionDetection(physicsClientId=shadow)
        for pt in p.getContactPoints(robot, robot, physicsClientId=shadow):
            # (flag, bodyA, bodyB, linkA, linkB, ..., distance at 8): self collision is a touch
            if pt[8] < 0.0 and (pt[3] in moving_set or pt[4] in moving_set):
                return "self"
        if near is None:
            near = _near(np.array([p.getAABB(robot, k, physicsClientId=shadow) for k in moving]),  # (M, 2, 3)
                         cache["boxes"])
        e = _too_close(shadow, robot, moving, cache["bodies"], near)
        return cache["names"][e] if e >= 0 else ""

    closed = []

    def close():
        # Once only: PyBullet reuses client ids, so a second disconnect (the world's close, then
        # the garbage collector's finalizer) could cut off another, newer client.
        if not closed:
            closed.append(True)
            if p.isConnected(shadow):
                p.disconnect(shadow)

    return check_here, contextlib.nullcontext, close, near_fn


def make_collision_fns(world, obstacles: bool = True, resolution: float = 0.05, ignore=(),
                       method: str = "shadow",
                       max_travel: float | None = 2 * (OBSTACLE_MARGIN - TRACKING_ALLOWANCE)
                       ) -> CollisionFns:
    """Collision closures for ``world`` (a ``sim.world.World``).

    Parameters
    ----------
    obstacles : also check the containers, obstacles and items on the table; with False only
        self collision and the table are checked.
    resolution : largest joint step (rad) along ``segment_fn``'s segments; must be > 0.
    max_travel : largest motion (m) of any point of the arm and tool between two configurations
        ``segment_fn`` checks (None: only ``resolution``).
    ignore : names of scene objects never treated as obstacles (e.g. ``("bowl",)``).
    method : "shadow" (default, faster) or "inplace" (see the module docstring).
    """
    if not resolution > 0:
        raise ValueError(f"resolution must be > 0 rad, got {resolution}")
    if max_travel is not None and not max_travel > 0:
        raise ValueError(f"max_travel must be > 0 m or None, got {max_travel}")
    if method not in ("shadow", "inplace"):
        raise ValueError(f"method must be 'shadow' or 'inplace', got {method!r}")
    client, robot = world.client, world.robot
    joints = tuple(world.arm_joints)
    dof = len(joints)
    infos = [p.getJointInfo(robot, j, physicsClientId=client) for j in joints]
    lower = np.array([i[8] for i in infos])
    upper = np.array([i[9] for i in infos])
    moving, fixed, pairs = self_pairs(client, robot, joints)
    levers = joint_levers(world)  # (7,) m
    make = _shadow_checker if method == "shadow" else _inplace_checker
    check_here, restored, close, near_fn = make(world, joints, moving, fixed, pairs, bool(obstacles), set(ignore))

    def within(q) -> bool:
        return bool(np.all(q >= lower) and np.all(q <= upper))

    def as_q(q, name="q"):
        q = np.asarray(q, dtype=float)
        if q.shape != (dof,):
            raise ValueError(f"{name} must have shape ({dof},), got {q.shape}")
        return q

    def collision_fn(q) -> bool:
        """``q (7,) -> bool``: True when out of limits or in collision."""
        q = as_q(q)
        if not within(q):
            return True
        with restored():
            return check_here(q) != ""

    def hit_fn(Q) -> np.ndarray:
        """``Q (B, 7) -> (B,) str``: what each configuration hits, ``""`` where free."""
        Q = np.asarray(Q, dtype=float)
        if Q.ndim != 2 or Q.shape[1] != dof:
            raise ValueError(f"Q must have shape (B, {dof}), got {Q.shape}")
        ok = np.all((Q >= lower) & (Q <= upper), axis=1)
        out = np.where(ok, "", "limits").astype(object)
        idx = np.flatnonzero(ok)
        near = near_fn(Q[idx])  # (B', M, E) or None
        with restored():
            for n, i in enumerate(idx):
                out[i] = check_here(Q[i]) if near is None else check_here(Q[i], near[n])
        return out.astype(str)

    def batch_collision_fn(Q) -> np.ndarray:
        """``Q (B, 7) -> (B,) bool``."""
        return hit_fn(Q) != ""

    def segment_fn(q1, q2) -> bool:
        """True when the straight segment ``q1 -> q2`` leaves the limits or collides."""
        q1, q2 = as_q(q1, "q1"), as_q(q2, "q2")
        if not (within(q1) and within(q2)):
            return True
        dq = np.abs(q2 - q1)
        n = max(1, int(math.ceil(np.max(dq) / resolution)))
        if max_travel is not None:
            n = max(n, int(math.ceil(float(np.linalg.norm(levers * dq)) / max_travel)))
        with restored():
            for k in bisection_order(n):
                if check_here(q1 + (q2 - q1) * (k / n)) != "":
                    return True
        return False

    # the shadow client lives as long as any closure does (callers often keep only collision_fn),
    # and no longer than the world
    weakref.finalize(check_here, close)
    world.on_close(close)
    return CollisionFns(collision_fn, batch_collision_fn, segment_fn, hit_fn, float(resolution), bool(obstacles), method,
                        tuple(pairs), close)
