"""The plan a robot follows (``sim.follow.PlanFollower``): where a new plan may take over."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pybullet")
from lfd.timing import plan_segments  # noqa: E402
from sim.follow import PlanFollower  # noqa: E402


def _follower():
    Q = np.array([[0.0] * 7, [0.3] + [0.0] * 6, [0.3, 0.4] + [0.0] * 5, [0.3, 0.4, 0.2] + [0.0] * 4])
    segs = plan_segments(Q, np.array([0, 0, 1, 2]), np.full(7, 2.0), 0.1, 0.5, None, 2.0)
    return PlanFollower(segs, "min-jerk", 2)


def test_a_new_plan_takes_over_at_a_waypoint_where_the_arm_is_at_rest():
    """Mid-edge, the arm moves at speed; a plan that took over there would start from rest and
    stop it dead in one step. ``at_rest_after`` gives the next waypoint, where the min-jerk
    profile is at rest, and following the plan there ends at that waypoint with zero velocity."""
    f = _follower()
    mid = f.predict(0.5 * f.segs[0][2])
    assert mid[0] == 0 and 0 < mid[1] < f.segs[0][2]
    speeds = []
    while f.position < mid:
        speeds.append(np.abs(f.advance()[1]).max())
    assert speeds[-1] > 0.1  # moving mid-edge
    rest = f.at_rest_after(mid)
    assert rest == (1, 0.0) and np.array_equal(f.q_at(rest), f.segs[0][1])
    while f.position < rest:
        q, qdot = f.advance()
    assert f.position == rest and np.abs(qdot).max() == 0.0 and np.allclose(q, f.segs[0][1])
    assert f.at_rest_after(rest) == rest  # already at a waypoint
    end = (len(f.segs), 0.0)
    assert f.at_rest_after(end) == end and f.step_at(end) == 2
