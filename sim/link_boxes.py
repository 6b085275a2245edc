"""Bounding boxes of the arm's moving links for a whole batch of configurations at once.

The collision checks (``sim.collision``) measure exact distances only for the (link, scene body)
pairs whose axis-aligned boxes come within the obstacle margin; asking PyBullet for the 16 moving
links' boxes one configuration at a time (``getAABB``) was a third of a check. ``LinkBoxes``
computes boxes that contain PyBullet's for a batch ``Q (B, 7)`` from one forward-kinematics pass
(``lfd.robot.kinematics.KinematicModel.frame_poses``, pytorch-kinematics on the robot's URDF):

* each moving link hangs at a fixed transform ``T_frame_link`` from the nearest frame of the
  chain to the end link (the arm's joints are all on it; the fingers and the tool are fixed);
* each link carries a box in its own frame that holds what ``getAABB`` bounds: the intersection,
  over sampled configurations, of the link-frame bounding boxes of its world ``getAABB`` boxes;
* in a configuration, the link's box is the world bounding box of that box, moved with the link.

Such a box contains ``getAABB``'s in every configuration (whatever ``getAABB`` bounds is rigid in
the link's frame and inside each sampled box), so the pairs it selects are a superset of the exact
ones, and the distances decide as before: the same answers
(``tests/test_collision.py::test_batched_boxes_hold_pybullets_and_give_the_same_answers``).
"""

from __future__ import annotations

import numpy as np
import torch

from sim.arm_geometry import link_tree
from sim.bullet import p
from sim.world import pose_to_matrix

__all__ = ["LinkBoxes"]

# A configuration's boxes are computed in one batch from this many configurations on; below it
# the forward pass's fixed cost (about 1 ms) outweighs PyBullet's boxes (about 40 us a configuration).
MIN_BATCH = 32


def _link_frame(client: int, body: int, link: int) -> np.ndarray:
    """``T_world_link (4, 4)``: the URDF frame of ``link`` (-1: the base) in ``client``'s world."""
    if link >= 0:
        state = p.getLinkState(body, link, computeForwardKinematics=True, physicsClientId=client)
        return pose_to_matrix(state[4], state[5])
    T_world_com = pose_to_matrix(*p.getBasePositionAndOrientation(body, physicsClientId=client))
    info = p.getDynamicsInfo(body, -1, physicsClientId=client)
    return T_world_com @ np.linalg.inv(pose_to_matrix(info[3], info[4]))


def _corners(box: np.ndarray) -> np.ndarray:
    """The 8 corners ``(8, 3)`` of ``box (2, 3)`` (min, max)."""
    idx = np.array(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")).reshape(3, 8).T  # (8, 3)
    return box[idx, np.arange(3)]


class LinkBoxes:
    """Boxes ``(B, M, 2, 3)`` (min, max corners, world frame) that contain PyBullet's ``getAABB``
    of each of the ``links`` (M) of ``robot`` in ``client``, for configurations ``Q (B, d)`` of
    ``joints``.

    Set up from the robot as it stands in ``client`` (its other joints, the fingers, held where
    they are): it samples ``samples`` configurations there and restores the arm's joints after.
    ``kin`` is the arm's ``KinematicModel`` (its chain must hold every one of ``joints``).

    Raises
    ------
    RuntimeError
        when the forward kinematics and PyBullet disagree about where a link is (another URDF).
    """

    def __init__(self, client: int, robot: int, joints, links, kin, samples: int = 64, seed: int = 0):
        self.kin = kin
        parent, names = link_tree(client, robot)
        frames = {n: i for i, n in enumerate(kin.frame_names)}
        names[-1] = kin.frame_names[0]  # the base is the chain's root

        def chain_frame(link: int) -> int:
            while names[link] not in frames:
                link = parent[link]
            return frames[names[link]]

        self.frame = np.array([chain_frame(k) for k in links])  # (M,) index into the chain's frames
        joints = list(joints)
        infos = [p.getJointInfo(robot, j, physicsClientId=client) for j in joints]
        lower, upper = np.array([i[8] for i in infos]), np.array([i[9] for i in infos])
        saved = [s[0] for s in p.getJointStates(robot, joints, physicsClientId=client)]
        Q = np.random.default_rng(seed).uniform(lower, upper, (samples, len(joints)))  # (S, d)
        T_world_frame = self._frames(Q)                                                 # (S, L, 4, 4)
        lo = np.full((len(links), 3), -np.inf)
        hi = np.full((len(links), 3), np.inf)
        T_frame_link = np.zeros((len(links), 4, 4))
        try:
            for s, q in enumerate(Q):
                p.resetJointStatesMultiDof(robot, joints, [[v] for v in q.tolist()], physicsClientId=client)
                for m, k in enumerate(links):
                    T_world_link = _link_frame(client, robot, k)
                    T = np.linalg.inv(T_world_frame[s, self.frame[m]]) @ T_world_link
                    if s == 0:
                        T_frame_link[m] = T
                    elif not np.allclose(T, T_frame_link[m], atol=1e-6):
                        raise RuntimeError(
                            f"link {names[k]!r}: the arm's forward kinematics ({kin.urdf_path.name}) and "
                            f"PyBullet disagree about where it is; is the world's robot another URDF?")
                    box = np.asarray(p.getAABB(robot, k, physicsClientId=client))       # (2, 3)
                    local = (_corners(box) - T_world_link[:3, 3]) @ T_world_link[:3, :3]  # (8, 3)
                    lo[m] = np.maximum(lo[m], local.min(axis=0))
                    hi[m] = np.minimum(hi[m], local.max(axis=0))
        finally:
            p.resetJointStatesMultiDof(robot, joints, [[v] for v in saved], physicsClientId=client)
        self.T_frame_link = T_frame_link                       # (M, 4, 4)
        self.centre = (lo + hi) / 2                            # (M, 3) link frame
        self.half = (hi - lo) / 2 + 1e-6                       # (M, 3), a micrometre for rounding

    def _frames(self, Q: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.kin.frame_poses(torch.as_tensor(Q, dtype=self.kin.dtype)).cpu().numpy()

    def __call__(self, Q: np.ndarray) -> np.ndarray:
        """``Q (B, d)`` -> ``(B, M, 2, 3)``."""
        T_world_frame = self._frames(np.asarray(Q, dtype=float))              # (B, L, 4, 4)
        T_world_link = T_world_frame[:, self.frame] @ self.T_frame_link       # (B, M, 4, 4)
        R = T_world_link[..., :3, :3]                                         # (B, M, 3, 3)
        centre = (R @ self.centre[..., None])[..., 0] + T_world_link[..., :3, 3]  # (B, M, 3)
        half = (np.abs(R) @ self.half[..., None])[..., 0]                         # (B, M, 3)
        return np.stack([centre - half, centre + half], axis=2)
