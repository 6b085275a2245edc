"""The arm's geometry as the collision checks and the planner need it: which link pairs can
collide (``self_pairs``), how far any point of the arm and tool moves per radian of each joint
(``joint_levers``), and how far the arm and the task's tool reach around the line through the
joint origins and the tool point (``sweep_margin``).
"""

from __future__ import annotations

import numpy as np

from sim.bullet import p

__all__ = ["ALWAYS_TOUCHING", "LINK_RADIUS", "joint_levers", "link_tree", "self_pairs", "sweep_margin"]

# Pairs of (link, link) names not checked: Baxter's collision shapes overlap there at (nearly)
# all configurations (share of 300 uniform random configurations in contact, measured).
ALWAYS_TOUCHING = frozenset(frozenset(pair) for pair in (
    ("left_lower_elbow", "left_upper_elbow_visual"),        # 100 %
    ("left_lower_forearm", "left_upper_forearm_visual"),    # 100 %
    ("left_lower_shoulder", "torso"),                       # 88 %
    ("left_upper_shoulder", "left_upper_elbow"),            # 81 %
    ("left_wrist", "left_upper_forearm_visual"),            # 62 %
    ("left_upper_elbow", "torso"),                          # 55 %
    # Not frequent, but a mesh artifact: the convex hulls overlap as soon as left_e1 > 1.95 rad
    # (the overlap depends on left_e1 alone), and Rethink's own tuck pose (e1 = 2.55, folded
    # safely on the real robot) overlaps by 3.4 cm. Keeping the pair would forbid the folded
    # elbow a person uses to hold a tool level close to the body.
    ("left_upper_forearm", "left_upper_elbow_visual"),
))
def link_tree(client, robot):
    """``(parent, names)``: the parent link of each link index, and each link's name (-1: ``"base"``)."""
    parent, names = {}, {-1: "base"}
    for j in range(p.getNumJoints(robot, physicsClientId=client)):
        info = p.getJointInfo(robot, j, physicsClientId=client)
        parent[j], names[j] = info[16], info[12].decode()
    return parent, names


def _arm_joints_between(a, b, parent, arm_joints):
    """Number of arm joints on the tree path between links ``a`` and ``b``."""
    def chain(x):
        out = [x]
        while x != -1:
            x = parent[x]
            out.append(x)
        return out
    ca, cb = chain(a), chain(b)
    common = next(x for x in ca if x in cb)
    path = ca[:ca.index(common)] + cb[:cb.index(common)]  # links whose parent joint is on the path
    return sum(1 for x in path if x in arm_joints)


def self_pairs(client, robot, joints):
    """Moving links with shapes, robot links with shapes, and the (moving, other) pairs to check."""
    parent, names = link_tree(client, robot)
    has_shape = [k for k in parent if p.getCollisionShapeData(robot, k, physicsClientId=client)]

    def moves(k):
        while k != -1:
            if k in joints:
                return True
            k = parent[k]
        return False

    moving = [k for k in has_shape if moves(k)]
    fixed = [k for k in has_shape if not moves(k)]
    pairs = [(a, b) for i, a in enumerate(moving) for b in fixed + moving[i + 1:]
             if _arm_joints_between(a, b, parent, joints) >= 2
             and frozenset({names[a], names[b]}) not in ALWAYS_TOUCHING]
    return moving, fixed, pairs


def joint_levers(world) -> np.ndarray:
    """``(7,)`` for each arm joint, an upper bound (m) on the distance of any point of the links
    after it (arm, gripper, tool) from its axis: the summed distances between the following joint
    origins and the gripper, plus the tool's reach from the gripper origin. Fixed link lengths,
    so it holds in every configuration."""
    from sim import assets

    c = world.client
    origins = [np.asarray(p.getLinkState(world.robot, j, physicsClientId=c)[4]) for j in world.arm_joints]
    origins.append(np.asarray(p.getLinkState(world.robot, world.ee_link, physicsClientId=c)[4]))
    links = np.linalg.norm(np.diff(np.stack(origins), axis=0), axis=1)  # (7,) joint j -> next
    reach = max(float(np.linalg.norm(np.abs(centre) + np.abs(half)))
                for centre, half, _ in assets.tool_boxes(world.task))
    reach = max(reach, 0.15)  # the gripper's fingers
    return np.cumsum(links[::-1])[::-1] + reach


LINK_RADIUS = 0.08  # m: Baxter's arm links and fingers reach this far from the line of joint origins


def sweep_margin(task: str, tool_point) -> float:
    """Metres around the arm's polyline of joint origins and the segment from the gripper to the
    model's tool point ``(3,)`` (gripper frame) within which the arm and the task's tool lie: the
    farthest tool-box corner from that segment, or the links' radius, whichever is larger. What
    ``lfd.planning.planner.PlannerSettings.sweep_margin`` needs for this robot and tool."""
    from sim import assets

    tool = np.asarray(tool_point, dtype=float).reshape(3)
    far = 0.0
    for centre, half, quat in assets.tool_boxes(task):
        R = np.asarray(p.getMatrixFromQuaternion(quat)).reshape(3, 3)
        for signs in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T:
            x = np.asarray(centre) + R @ (signs * np.asarray(half))
            s = float(np.clip(x @ tool / max(tool @ tool, 1e-12), 0.0, 1.0))
            far = max(far, float(np.linalg.norm(x - s * tool)))
    return max(far + 0.01, LINK_RADIUS)
