"""When a plan's waypoints are reached: the pace of execution (numpy only).

A plan of the spatiotemporal roadmap is a path of ``(q, t)`` pairs: configurations, and the task's
time step at each. The path fixes where the arm goes, not when. This module times it:

* a roadmap edge (``q`` changes, ``t`` constant) is moved as fast as the joint limits allow
  (constant speed, or a rest-to-rest minimum-jerk profile within an acceleration limit);
* a time-step transition ``t0 -> t1`` (``q`` constant) waits until the robot has been in step
  ``t0`` as long as the demonstrations took, on average, to get from step ``t0`` to step ``t1``.

That average comes from the learned transition chain (``step_clock``): ``clock[t]`` is the
expected time at which the chain, started in step 0, first reaches a step ``>= t``. Waits are
differences of one clock, so they telescope: however a plan skips steps (``t -> t + 2`` is a
permitted transition, and the search often takes it because a path with fewer edges costs less),
the time it spends from step ``a`` to step ``b`` is ``clock[b] - clock[a]``, the demonstrations'
mean. Pouring and dumping need that time: a pitcher tilted for half the demonstrated time
leaves liquid in it.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["PROFILES", "expected_sojourn", "plan_segments", "profile_at", "step_clock"]

PROFILES = ("min-jerk", "linear")
# min-jerk s(a) = 10a^3 - 15a^4 + 6a^5 on a in [0, 1]: peak ds/da = 15/8, peak d2s/da2 = 10/sqrt(3)
_MJ_PEAK_V, _MJ_PEAK_A = 1.875, 10.0 / math.sqrt(3.0)
_MIN_LEAVE = 1e-3  # smallest probability of leaving a step (caps a step's expected stay at 1000 dt)


def _checked(log_trans: np.ndarray, offsets) -> tuple[np.ndarray, list[int]]:
    offsets = [int(o) for o in offsets]
    if not offsets:
        raise ValueError("offsets must not be empty")
    log_trans = np.asarray(log_trans, dtype=float)
    if log_trans.ndim != 2 or log_trans.shape[1] != len(offsets):
        raise ValueError(f"log_trans must have shape (T, {len(offsets)}) for offsets {offsets}, "
                         f"got {log_trans.shape}")
    if sorted(set(offsets)) != offsets or offsets[0] < 0:
        raise ValueError(f"offsets must be increasing and non-negative, got {offsets}")
    return np.exp(log_trans), offsets


def expected_sojourn(log_trans: np.ndarray, offsets, dt: float) -> np.ndarray:
    """``(T,)`` expected seconds per visit of each time step: ``dt / (1 - p(t | t))``.

    ``log_trans (T, K)``: ``log p(t + offsets[k] | t)``. Without offset 0 every step lasts ``dt``.
    """
    P, offsets = _checked(log_trans, offsets)
    if 0 not in offsets:
        return np.full(len(P), float(dt))
    return dt / np.clip(1.0 - P[:, offsets.index(0)], _MIN_LEAVE, 1.0)


def step_clock(log_trans: np.ndarray, offsets, dt: float) -> np.ndarray:
    """``(T,)`` expected time (s) at which the learned chain, started in step 0, first reaches a
    step ``>= t``; ``clock[0] = 0`` and the clock never decreases.

    First passage into ``{>= t}``: ``h(s) = dt + sum_k p(s + o_k | s) h(s + o_k)`` for ``s < t``
    with ``h = 0`` from ``t`` on (one sample of ``dt`` per visit, self-transitions included, so a
    step the chain usually skips adds little and one it always visits adds its full sojourn).
    ``clock[t + 1] - clock[t]`` is the chain's mean time in step t per run, runs that skip it
    included; it equals ``expected_sojourn[t]`` when no
    transition skips a step.
    """
    P, offsets = _checked(log_trans, offsets)
    T = len(P)
    stay = P[:, offsets.index(0)] if 0 in offsets else np.zeros(T)
    moves = [(k, o) for k, o in enumerate(offsets) if o > 0]
    clock = np.zeros(T)
    for target in range(1, T):
        h = np.zeros(target + max(offsets) + 1)
        for s in range(target - 1, -1, -1):
            ahead = sum(P[s, k] * h[s + o] for k, o in moves if s + o < target)
            h[s] = (dt + ahead) / max(1.0 - stay[s], _MIN_LEAVE)
        clock[target] = h[0]
    return np.maximum.accumulate(clock)


def profile_at(a: float, profile: str = "min-jerk") -> tuple[float, float]:
    """Progress ``s`` and its rate ``ds/da`` at phase ``a`` in [0, 1] of a segment."""
    if profile == "linear":
        return a, 1.0
    return a ** 3 * (10 - 15 * a + 6 * a * a), 30 * a * a * (1 - a) ** 2


def plan_segments(configurations: np.ndarray, time_steps: np.ndarray, vmax: np.ndarray, dt: float,
                  speed: float, clock: np.ndarray | None = None, accel: float | None = None,
                  elapsed: float = 0.0) -> list[tuple[np.ndarray, np.ndarray, float, int]]:
    """Timed segments ``(q_from, q_to, duration_s, time_step)`` of a plan.

    configurations : (N, d) the plan's waypoints; time_steps : (N,) its task time steps.
    vmax : (d,) joint velocity limits; speed : the fraction of them used.

    A roadmap edge (q changes, t constant) takes ``max_j |dq_j| / (speed vmax_j)`` at constant
    speed; with ``accel`` (rad/s^2) it is timed for the min-jerk profile instead, the shortest
    duration whose peak speed ``1.875 |dq_j| / T`` and peak acceleration ``5.77 |dq_j| / T^2`` stay
    within ``speed vmax_j`` and ``accel`` for every joint. A time-step transition ``t0 -> t1`` (q
    constant) dwells at least one sampling interval ``dt``; with ``clock (T,)`` (``step_clock``)
    it dwells until the robot has been in step ``t0`` for ``clock[t1] - clock[t0]`` seconds,
    motion included; ``elapsed`` is the time already spent in the first step (a plan made
    mid-step, after a re-plan). ``time_step`` is the task time step during the segment.
    """
    vmax = np.asarray(vmax, dtype=float)
    if not np.all(vmax > 0):  # 0 made 0/0: a NaN duration dropped the segment, the arm jumped
        raise ValueError(f"vmax must be positive joint velocity limits, got {vmax.tolist()}")
    segs = []
    spent = float(elapsed)
    for i in range(len(configurations) - 1):
        q0, q1 = configurations[i], configurations[i + 1]
        t0, t1 = int(time_steps[i]), int(time_steps[i + 1])
        dq = np.abs(q1 - q0)
        if accel is None:
            move = float(np.max(dq / (speed * vmax)))
        else:
            move = float(max(np.max(_MJ_PEAK_V * dq / (speed * vmax)),
                             np.sqrt(_MJ_PEAK_A * np.max(dq) / accel)))
        if move > 1e-9:
            segs.append((q0, q1, move, t0))
            spent += move
        if t1 != t0:
            wait = dt if clock is None else max(dt, float(clock[t1] - clock[t0]) - spent)
            segs.append((q1, q1, wait, t0))
            spent = 0.0
    return segs
