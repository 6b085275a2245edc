"""What makes recorded demonstrations unusable beyond their format: landmarks in other units or
frames, tracked landmarks that jump, an arm that never moves, one recording twice. Each check
returns why (one sentence) or ``None``; ``lfd.learning.demos`` (``.npz`` sets) and
``lfd.io.recordings`` (CSV recordings) raise their own errors with it."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["MAX_LANDMARK_DISTANCE", "MAX_LANDMARK_SPEED", "MIN_JOINT_TRAVEL", "far_landmark", "jumping_landmark",
           "other_task_dt", "same_interval", "unusable_demos"]

MAX_LANDMARK_DISTANCE = 20.0  # m from the robot's base: a landmark farther was given in other units
MAX_LANDMARK_SPEED = 5.0  # m/s: a tracked landmark faster than this between samples is a tracking glitch
MIN_JOINT_TRAVEL = 0.01  # rad: a demonstration in which no joint moves more than this shows no motion


def far_landmark(poses: np.ndarray, names: Sequence[str]) -> str | None:
    """Why landmark poses ``(Z, 4, 4)`` or, tracked, ``(S, Z, 4, 4)`` cannot be metres in the
    robot's base frame (a landmark farther than ``MAX_LANDMARK_DISTANCE`` from it), or ``None``."""
    dist = np.linalg.norm(poses[..., :3, 3], axis=-1)  # (Z,) or (S, Z)
    if dist.size == 0 or float(dist.max()) <= MAX_LANDMARK_DISTANCE:
        return None
    idx = np.unravel_index(int(np.argmax(dist)), dist.shape)
    at = f" at sample {int(idx[0])}" if dist.ndim == 2 else ""
    return (f"landmark {names[int(idx[-1])]!r} is {float(dist[idx]):.4g} m from the robot's base{at}, more than "
            f"{MAX_LANDMARK_DISTANCE:g} m (millimetres given as metres, or another frame than the base's?)")


def jumping_landmark(poses: np.ndarray, names: Sequence[str], dt: float | np.ndarray) -> str | None:
    """Why tracked landmark poses ``(S, Z, 4, 4)``, sampled every ``dt`` s (a number, or the
    ``(S - 1,)`` intervals of readings at their own times), cannot be one object's motion (a
    landmark faster than ``MAX_LANDMARK_SPEED`` between two samples), or ``None``; ``None`` for
    landmarks held still ``(Z, 4, 4)``."""
    if poses.ndim != 4 or poses.shape[0] < 2:
        return None
    step = np.linalg.norm(np.diff(poses[:, :, :3, 3], axis=0), axis=-1)  # (S - 1, Z) m
    speed = step / np.broadcast_to(np.reshape(np.asarray(dt, dtype=float), (-1, 1)), step.shape)
    if float(speed.max()) <= MAX_LANDMARK_SPEED:
        return None
    s, z = (int(i) for i in np.unravel_index(int(np.argmax(speed)), speed.shape))
    return (f"landmark {names[z]!r} moves {float(step[s, z]):.3g} m between samples {s} and {s + 1} "
            f"({float(speed[s, z]):.3g} m/s, more than {MAX_LANDMARK_SPEED:g} m/s: a tracking glitch, or "
            f"another marker read as this landmark?)")


def same_interval(dt: float, dt0: float) -> bool:
    """Whether two sampling intervals (s) are the same, but for rounding."""
    return abs(dt - dt0) <= 1e-9 * max(1.0, dt0)


def other_task_dt(task_dt: float, dt: float) -> str | None:
    """Why a task whose ``dt`` is ``task_dt`` cannot be the task of demonstrations sampled every
    ``dt`` s (a learned model's time step is its task's ``dt``, the samples' own interval), or
    ``None``."""
    if same_interval(task_dt, dt):
        return None
    return (f"dt={task_dt} differs from the demonstrations' sampling interval dt={dt} (the model's dt comes "
            f"from the task)")


def unusable_demos(qs: Sequence[np.ndarray], names: Sequence[str]) -> str | None:
    """Why demonstrations with joint trajectories ``qs`` (each ``(S, d)``) and ``names`` cannot be
    learned from as they are, or ``None``: one in which no joint travels ``MIN_JOINT_TRAVEL``
    (the arm never moved: a recording that missed the motion), or two with the same joint
    trajectory (one recording saved twice would count twice in the model)."""
    for i, (q, name) in enumerate(zip(qs, names)):
        travel = float(np.ptp(q, axis=0).max()) if len(q) else 0.0
        if travel < MIN_JOINT_TRAVEL:
            return (f"demonstration {name or i!r}: no joint moves more than {travel:.2g} rad: the arm never "
                    f"moved (at least {MIN_JOINT_TRAVEL:g} rad is expected of a demonstration)")
        for q0, name0 in zip(qs[:i], names[:i]):
            if q0.shape == q.shape and np.array_equal(q0, q):
                return (f"demonstrations {name0!r} and {name!r} have the same joint trajectory: one "
                        f"recording twice? (each would count as a demonstration of its own)")
    return None
