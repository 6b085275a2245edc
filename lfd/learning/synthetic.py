"""Demonstrations drawn from a known task model, for tests and measurements of the learner.

A real ``KinematicModel`` (Baxter's left arm) is driven by batched damped-least-squares IK
so that the tool point ``tool`` (end-effector frame) lands at targets drawn, per time step,
from known Gaussians ``N(m_t, C_t)`` in the frame of one landmark (``true_landmark``) among
``Z``; the null space pulls each configuration towards a per-step nominal configuration
plus a per-demonstration offset. Optionally the first ``fixed_steps`` steps are fixed in the
robot's (world) frame instead, like the start above the source container.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch

from lfd.learning.demoset import Demonstration, DemoSet
from lfd.learning.tasks import is_real
from lfd.robot.robots import BAXTER_LEFT, PANDA, RobotSpec

__all__ = ["SyntheticTruth", "as_handover", "beyond_two_landmarks", "make_synthetic", "random_rotation"]

Q_START = np.array([0.3, -0.6, -0.3, 1.4, 0.3, 0.8, 0.0])
Q_END = np.array([-0.1, -0.2, 0.2, 1.2, -0.4, 0.6, 0.9])
# per built-in robot: the nominal arm postures at the start and the end of a demonstration, and
# the box (low, high corners, m) in which the landmarks are placed, within the arm's reach
ARMS = {
    BAXTER_LEFT.name: (Q_START, Q_END, ((0.55, -0.1, -0.15), (0.95, 0.6, 0.15))),
    PANDA.name: (np.array([0.3, -0.5, 0.0, -2.2, 0.0, 1.8, 0.8]), np.array([-0.2, -0.1, 0.1, -1.9, 0.1, 1.9, 1.2]),
                 ((0.35, -0.25, 0.0), (0.6, 0.25, 0.2))),
}


@dataclass(frozen=True)
class SyntheticTruth:
    tool: np.ndarray  # (3,)
    true_landmark: int
    means: np.ndarray  # (T, 3) tool point in the landmark frame (world frame for fixed steps)
    stds: np.ndarray  # (T, 3) per-axis standard deviations
    alignments: tuple  # per demo (S_m,) 0-based steps
    fixed_steps: int


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _ik(kin, q0, q_nom, targets, tool, iters=60, damping=0.02, null_gain=0.3):
    """Batched DLS IK of the tool point: ``q0, q_nom (B, d)``, ``targets (B, 3)`` -> q, error."""
    q = q0.clone()
    tool_t = torch.as_tensor(tool, dtype=q.dtype)
    eye_d = torch.eye(q.shape[1], dtype=q.dtype)
    for _ in range(iters):
        T = kin.fk(q)
        r = T[:, :3, :3] @ tool_t  # (B, 3)
        p = r + T[:, :3, 3]
        e = targets - p
        J = kin.jacobian(q)  # (B, 6, d)
        skew = torch.zeros(q.shape[0], 3, 3, dtype=q.dtype)
        skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
        skew = skew - skew.transpose(1, 2)
        Jp = J[:, :3] - skew @ J[:, 3:]  # (B, 3, d): d/dq of p = t + R tool
        JJt = Jp @ Jp.transpose(1, 2) + damping ** 2 * torch.eye(3, dtype=q.dtype)
        pinv = Jp.transpose(1, 2) @ torch.linalg.inv(JJt)  # (B, d, 3)
        null = eye_d - pinv @ Jp
        dq = (pinv @ e[:, :, None])[..., 0] + null_gain * (null @ (q_nom - q)[:, :, None])[..., 0]
        q = torch.clamp(q + dq, kin.lower, kin.upper)
    T = kin.fk(q)
    err = (targets - (T[:, :3, :3] @ tool_t + T[:, :3, 3])).norm(dim=1)
    return q, err


def _landmarks_and_targets(rng, align, Z, box, rotations, means, stds, fixed_steps, true_landmark,
                           landmark_motion):
    """One demonstration's landmarks (``(Z, 4, 4)``, or tracked ``(S, Z, 4, 4)`` with
    ``landmark_motion``) placed in ``box``, and its task-point targets ``(S, 3)`` in the world:
    the per-step means plus noise, relative to the true landmark after ``fixed_steps``."""
    lo, hi = box
    lm = np.tile(np.eye(4), (Z, 1, 1))
    for i in range(3):
        lm[:, i, 3] = rng.uniform(lo[i], hi[i], Z)
    if rotations:
        for z in range(Z):
            lm[z, :3, :3] = random_rotation(rng)
    x = means[align] + stds[align] * rng.normal(size=(len(align), 3))  # (S, 3)
    targets = x.copy()
    rel = align >= fixed_steps
    L = lm[true_landmark]
    if landmark_motion:
        heading = rng.uniform(0, 2 * np.pi)
        travel = np.linspace(0.0, landmark_motion, len(align))[:, None] * [np.cos(heading), np.sin(heading), 0.0]
        lm = np.repeat(lm[None], len(align), axis=0)  # (S, Z, 4, 4): tracked
        lm[:, true_landmark, :3, 3] += travel
        targets[rel] = x[rel] @ L[:3, :3].T + L[:3, 3] + travel[rel]
    else:
        targets[rel] = x[rel] @ L[:3, :3].T + L[:3, 3]
    return lm, targets


def make_synthetic(kin, n_demos=11, time_steps=8, samples_per_step=(6, 11), Z=5, true_landmark=0,
                   tool=(0.03, -0.02, 0.15), fixed_steps=0, rotations=False, seed=0,
                   task=None, demo_spread=0.1, std_scale=1.0, dt=None,
                   landmark_motion=0.0, robot: RobotSpec = BAXTER_LEFT) -> tuple[DemoSet, SyntheticTruth]:
    """A ``DemoSet`` and the ``SyntheticTruth`` it was drawn from (see the module docstring).

    ``landmark_motion``: metres the true landmark travels, at constant speed in a random horizontal
    direction, during each demonstration (a hand moving towards the robot in a handover); the task
    follows it, and the landmarks are then tracked, ``(S, Z, 4, 4)`` per demonstration.
    ``robot``: a built-in arm (``ARMS``: its postures and the landmarks' box); ``kin`` must be its model.

    ``dt``: the sampling interval written into every demonstration; default the ``task``'s
    (``TaskSpec.dt``), 0.1 s without a task, so that a set saved with its task loads again.
    """
    if dt is None:
        dt = task.dt if task is not None else 0.1
    if not (is_real(dt) and math.isfinite(dt) and float(dt) > 0):
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
    rng = np.random.default_rng(seed)
    T = time_steps
    s = np.linspace(0, 1, T)[:, None]
    # approach from 25 cm above and behind the landmark, end 5 cm above it
    means = (1 - s) * np.array([-0.10, 0.05, 0.25]) + s * np.array([0.0, 0.0, 0.05])
    stds = std_scale * np.tile([0.006, 0.008, 0.005], (T, 1)) * (1 + 1.0 * (1 - s))
    if fixed_steps:
        means[:fixed_steps] = np.array([0.55, 0.55, 0.25])  # world frame: above a "source"
        stds[:fixed_steps] = [0.01, 0.01, 0.01]
    if robot.name not in ARMS:
        raise ValueError(f"no synthetic demonstrations for robot {robot.name!r}; built in: {', '.join(ARMS)}")
    q_start, q_end, (lo, hi) = ARMS[robot.name]
    q_nom_steps = (1 - s) * q_start + s * q_end  # (T, d)
    tool = np.asarray(tool, dtype=float)
    lms, aligns, all_targets, all_nom = [], [], [], []
    for m in range(n_demos):
        counts = rng.integers(samples_per_step[0], samples_per_step[1] + 1, size=T)
        align = np.repeat(np.arange(T), counts)
        lm, targets = _landmarks_and_targets(rng, align, Z, (lo, hi), rotations, means, stds, fixed_steps,
                                             true_landmark, landmark_motion)
        d = len(robot.joint_names)
        q_nom = q_nom_steps[align] + demo_spread * rng.normal(size=d) + 0.02 * rng.normal(size=(len(align), d))
        lms.append(lm)
        aligns.append(align)
        all_targets.append(targets)
        all_nom.append(q_nom)
    q_nom = torch.as_tensor(np.concatenate(all_nom))
    q, err = _ik(kin, q_nom, q_nom, torch.as_tensor(np.concatenate(all_targets)), tool)
    if float(err.max()) > 2e-3:
        raise RuntimeError(f"synthetic IK did not converge (max error {float(err.max()):.3g} m)")
    splits = np.cumsum([len(a) for a in aligns])[:-1]
    demos = [Demonstration(q=qm, dt=float(dt), landmarks=lm, name=f"synth_{m:02d}")
             for m, (qm, lm) in enumerate(zip(np.split(q.numpy(), splits), lms))]
    names = tuple(["bowl"] + [f"lm{i}" for i in range(1, Z)])
    if true_landmark != 0:
        names = tuple(f"lm{i}" for i in range(Z))
    ds = DemoSet(demos=tuple(demos), joint_names=robot.joint_names, landmark_names=names,
                 robot=robot, task=task)
    return ds, SyntheticTruth(tool=tool, true_landmark=true_landmark, means=means, stds=stds,
                              alignments=tuple(aligns), fixed_steps=fixed_steps)


def as_handover(ds: DemoSet, rng: np.random.Generator, hand_sd: float = 0.03, torso_sd: float = 0.01) -> DemoSet:
    """A set of ``make_synthetic(landmark_motion=...)`` (tracked landmarks, the true one first) as a
    handover whose hand and body the data can hardly tell apart: the true landmark, renamed ``hand``,
    sensed ``hand_sd`` m per axis away from where the task happens (one offset per demonstration: the
    person holds out the hand a little differently each time), and a ``torso`` landmark appended that
    moves rigidly with that hand, 30 cm beside and 10 cm below it, plus its own per-demonstration
    offset of ``torso_sd`` m per axis. ``hand_sd=0`` keeps the hand exact: then the hand is the
    better landmark on every demonstration."""
    demos = []
    for d in ds.demos:
        lm = np.array(d.landmarks)  # (S, Z, 4, 4)
        if lm.ndim != 4:
            raise ValueError("as_handover needs tracked landmarks: make_synthetic(landmark_motion=...)")
        lm[:, 0, :3, 3] += rng.normal(0, hand_sd, 3)
        torso = lm[:, 0].copy()
        torso[:, :3, 3] += np.array([0.3, 0.0, -0.1]) + rng.normal(0, torso_sd, 3)
        demos.append(replace(d, landmarks=np.concatenate([lm, torso[:, None]], axis=1)))
    return replace(ds, demos=tuple(demos), landmark_names=("hand", *ds.landmark_names[1:], "torso"))


def beyond_two_landmarks(ds: DemoSet, rng: np.random.Generator, spread: float = 0.2) -> DemoSet:
    """A set of ``make_synthetic`` (landmarks standing still, the true one first) whose true landmark
    is replaced by two, ``a`` (first) and ``b`` (last), placed so that it is ``1.5 a - 0.5 b``: a point
    beyond ``a`` on the line from ``b`` (a horizontal offset of up to ``spread`` m per axis from the
    true place to ``a``, three times that to ``b``, drawn per demonstration). Sum-to-one weights
    (1.5, -0.5) express it; weights on the simplex cannot."""
    demos = []
    for d in ds.demos:
        lm = np.array(d.landmarks)  # (Z, 4, 4)
        off = np.r_[rng.uniform(-spread, spread, 2), 0.0]
        a, b = lm[0].copy(), lm[0].copy()
        a[:3, 3] += off
        b[:3, 3] += 3 * off  # 1.5 (L + off) - 0.5 (L + 3 off) = L
        demos.append(replace(d, landmarks=np.concatenate([a[None], lm[1:], b[None]])))
    return replace(ds, demos=tuple(demos), landmark_names=("a", *ds.landmark_names[1:], "b"), task=None)
