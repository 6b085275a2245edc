"""Plan timing (lfd.timing): joint limits on edges, and the demonstrations' clock at step changes."""

from __future__ import annotations

import numpy as np
import pytest

from lfd.timing import expected_sojourn, plan_segments, profile_at, step_clock

VMAX = np.array([1.5] * 4 + [4.0] * 3)


def _chain(rng, T, offsets=(0, 1, 2)):
    """A random left-to-right chain: ``(T, K)`` log probabilities, no move past the last step."""
    P = rng.dirichlet(np.ones(len(offsets)), size=T)
    P[:, 0] = np.maximum(P[:, 0], 0.3)
    for t in range(T):
        for k, o in enumerate(offsets):
            if t + o >= T and o > 0:
                P[t, k] = 0.0
        P[t] /= P[t].sum()
    with np.errstate(divide="ignore"):
        return np.log(P)


def _simulated_first_passage(log_trans, offsets, dt, n=20000, seed=1):
    """Monte Carlo: mean time (s) at which the chain started in step 0 first reaches >= t."""
    rng = np.random.default_rng(seed)
    P = np.exp(log_trans)
    T = len(P)
    total = np.zeros(T)
    for _ in range(n):
        t, time_s, first = 0, 0.0, np.full(T, np.nan)
        first[0] = 0.0
        while t < T - 1:
            time_s += dt
            t_next = t + offsets[rng.choice(len(offsets), p=P[t])]
            first[t + 1:t_next + 1] = np.where(np.isnan(first[t + 1:t_next + 1]), time_s, first[t + 1:t_next + 1])
            t = t_next
        total += first
    return total / n


def test_step_clock_is_the_chains_mean_first_passage_time():
    rng = np.random.default_rng(0)
    offsets = (0, 1, 2)
    log_trans = _chain(rng, 7, offsets)
    clock = step_clock(log_trans, offsets, dt=0.1)
    mc = _simulated_first_passage(log_trans, offsets, 0.1)
    assert clock[0] == 0.0 and np.all(np.diff(clock) >= 0)
    np.testing.assert_allclose(clock, mc, rtol=0.03, atol=0.01)


def test_without_skips_the_clock_adds_up_the_sojourns():
    rng = np.random.default_rng(2)
    log_trans = _chain(rng, 9, (0, 1))
    soj = expected_sojourn(log_trans, (0, 1), dt=0.05)
    clock = step_clock(log_trans, (0, 1), dt=0.05)
    np.testing.assert_allclose(np.diff(clock), soj[:-1], rtol=1e-12)
    np.testing.assert_allclose(step_clock(np.zeros((4, 1)), (1,), dt=0.1), [0.0, 0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match="log_trans must have shape"):
        step_clock(log_trans, (0, 1, 2), dt=0.05)


def test_skipping_steps_keeps_the_demonstrated_time():
    """Waits are clock differences: a plan that jumps 0 -> 2 -> 4 at one configuration takes as
    long as one that visits every step, clock[4] - clock[0]. A step the chain mostly skips (step 2:
    entered from step 1 one time in ten, then stayed in for 2 s) adds its stay only that often,
    so one demonstration's long stay is not forced on every plan."""
    eps = 1e-12
    log_trans = np.log(np.array([[0.9, 0.1, eps], [0.5, 0.05, 0.45], [0.95, 0.05, eps],
                                 [0.6, 0.3, 0.1], [1.0, eps, eps]]))
    offsets, dt = (0, 1, 2), 0.1
    clock = step_clock(log_trans, offsets, dt)
    soj = expected_sojourn(log_trans, offsets, dt)                    # [1.0, 0.2, 2.0, 0.25, ...]
    assert clock[1] == pytest.approx(soj[0])
    assert clock[3] - clock[1] == pytest.approx(soj[1] + 0.1 * soj[2])  # 0.4 s, not 2.2 s
    q = np.zeros((5, 7))
    every = plan_segments(q, np.arange(5), VMAX, dt, 0.5, clock=clock)
    skip = plan_segments(q[:3], np.array([0, 2, 4]), VMAX, dt, 0.5, clock=clock)
    assert sum(s[2] for s in every) == pytest.approx(clock[4])
    assert sum(s[2] for s in skip) == pytest.approx(clock[4])


def test_plan_segments_respect_velocity_limits_and_pace():
    Q = np.array([np.zeros(7), np.full(7, 0.3), np.full(7, 0.3), np.full(7, 0.9)])
    steps = np.array([0, 0, 1, 1])
    log_trans = np.log(np.array([[0.9, 0.1, 1e-12], [0.5, 0.5, 1e-12]]))
    soj = expected_sojourn(log_trans, (0, 1, 2), dt=0.1)
    assert soj == pytest.approx([1.0, 0.2])
    clock = step_clock(log_trans, (0, 1, 2), dt=0.1)
    assert clock == pytest.approx([0.0, 1.0])
    segs = plan_segments(Q, steps, VMAX, dt=0.1, speed=0.5, clock=clock)
    move0, wait, move1 = segs
    assert move0[2] == pytest.approx(0.3 / (0.5 * 1.5))            # slowest joint at half its limit
    assert wait[2] == pytest.approx(1.0 - move0[2]) and wait[3] == 0  # step 0 lasts its expected time
    assert move1[2] == pytest.approx(0.6 / 0.75) and move1[3] == 1
    no_pace = plan_segments(Q, steps, VMAX, dt=0.1, speed=0.5)
    assert no_pace[1][2] == pytest.approx(0.1)                       # one sampling interval
    resumed = plan_segments(Q, steps, VMAX, dt=0.1, speed=0.5, clock=clock, elapsed=0.3)
    assert resumed[1][2] == pytest.approx(0.7 - move0[2])           # a re-plan made 0.3 s into step 0
    late = plan_segments(Q, steps, VMAX, dt=0.1, speed=0.5, clock=clock, elapsed=5.0)
    assert late[1][2] == pytest.approx(0.1)                          # overdue: one interval
    for bad in (0.0, -1.0, np.nan):  # a zero limit made 0/0: the segment was dropped, the arm jumped
        with pytest.raises(ValueError, match="vmax must be positive"):
            plan_segments(Q, steps, np.r_[VMAX[:-1], bad], dt=0.1, speed=0.5)


def test_min_jerk_segments_respect_speed_and_acceleration_limits():
    """Timed for the min-jerk profile, each edge's sampled joint speeds stay within speed * vmax
    and its accelerations within accel; the profile starts and ends at rest."""
    rng = np.random.default_rng(0)
    Q = np.cumsum(rng.uniform(-0.6, 0.6, (6, 7)), axis=0)
    segs = plan_segments(Q, np.zeros(6, int), VMAX, dt=0.1, speed=0.5, accel=2.0)
    a = np.linspace(0, 1, 2001)
    for q0, q1, dur, _ in segs:
        s = np.array([profile_at(x)[0] for x in a])
        q = q0 + s[:, None] * (q1 - q0)  # (N, 7)
        h = dur / (len(a) - 1)
        v = np.diff(q, axis=0) / h
        acc = np.diff(v, axis=0) / h
        assert np.all(np.abs(v) <= 0.5 * VMAX * (1 + 1e-3))
        assert np.abs(acc).max() <= 2.0 * (1 + 1e-2)
        assert max(np.abs(v).max() / (0.5 * VMAX).max(), np.abs(acc).max() / 2.0) > 0.5  # not needlessly slow
    assert profile_at(0.0) == (0.0, 0.0) and profile_at(1.0)[0] == pytest.approx(1.0)
    assert profile_at(1.0)[1] == pytest.approx(0.0)


def test_exec_settings_check_their_options():
    pytest.importorskip("pybullet")
    from sim.execute import ExecSettings
    with pytest.raises(ValueError, match="profile must be one of"):
        ExecSettings(profile="cubic")
    with pytest.raises(ValueError, match="pace must be one of"):
        ExecSettings(pace="slow")
    bad = {"record_every": 0, "frame_every": -1, "max_replans": 2.5, "success_fraction": 0.0, "settle_s": -1.0,
           "force": float("nan"), "accel": 0.0, "sense_period": float("inf"), "replan_threshold": -0.01}
    for name, value in bad.items():  # record_every=0 was a ZeroDivisionError mid-run
        with pytest.raises(ValueError, match=f"^{name} must be"):
            ExecSettings(**{name: value})
    assert ExecSettings(frame_every=0, max_replans=0, settle_s=0.0, success_fraction=1.0).record_every == 12
