"""The plan a robot is executing, timed: where along it the robot is and will be.

``PlanFollower`` holds a plan's timed segments ``(q0, q1, duration, time_step)`` (from
``lfd.timing.plan_segments``) and the robot's position along them, ``(i, t)``: segment i, t
seconds into it (``i == len``: done). It advances one simulation step at a time with the
segment's velocity profile and predicts where the robot will be after a latency (``sim.execute``
switches plans where the robot will be at rest).
"""

from __future__ import annotations

import numpy as np

from lfd.timing import profile_at
from sim import layout as L

__all__ = ["PlanFollower"]


class PlanFollower:
    """The plan being executed: its timed segments ``(q0, q1, duration, time_step)`` and the
    robot's position along them, ``(i, t)``: segment i, t seconds into it (``i == len``: done)."""

    def __init__(self, segs, profile: str, final_step: int, elapsed: float = 0.0):
        self.segs, self.profile, self.final_step = segs, profile, final_step
        self.elapsed0 = elapsed  # time already spent in the first segment's step
        self.i, self.t = 0, 0.0

    @property
    def done(self) -> bool:
        return self.i >= len(self.segs)

    @property
    def position(self) -> tuple[int, float]:
        return self.i, self.t

    def step_at(self, pos) -> int:
        return self.segs[pos[0]][3] if pos[0] < len(self.segs) else self.final_step

    def q_at(self, pos) -> np.ndarray:
        i, t = pos
        if i >= len(self.segs):
            return self.segs[-1][1]
        q0, q1, dur, _ = self.segs[i]
        prog, _ = profile_at(min(1.0, t / dur) if dur > 0 else 1.0, self.profile)
        return q0 + prog * (q1 - q0)

    def advance(self) -> tuple[np.ndarray, np.ndarray]:
        """One simulation step along the plan: ``(q_cmd, qdot)``."""
        q0, q1, dur, _ = self.segs[self.i]
        self.t += L.SIM_DT
        a = min(1.0, self.t / dur) if dur > 0 else 1.0
        prog, rate = profile_at(a, self.profile)
        q_cmd = q0 + prog * (q1 - q0)
        qdot = rate * (q1 - q0) / dur if dur > 0 and a < 1.0 else np.zeros_like(q0)
        if a >= 1.0:
            self.i, self.t = self.i + 1, 0.0
        return q_cmd, qdot

    def predict(self, seconds: float) -> tuple[int, float]:
        """Where the robot will be ``seconds`` from now (in whole simulation steps)."""
        i, t = self.i, self.t
        left = int(round(seconds / L.SIM_DT)) * L.SIM_DT
        while i < len(self.segs) and left > 1e-12:
            dur = self.segs[i][2]
            steps_left = max(0.0, dur - t)
            if left < steps_left - 1e-12:
                return i, t + left
            left -= steps_left
            i, t = i + 1, 0.0
        return i, t

    def at_rest_after(self, pos) -> tuple[int, float]:
        """The first waypoint at or after ``pos``: where a min-jerk plan is at rest. A new plan
        starts at rest, so one that took over in the middle of an edge stopped the arm dead, from
        up to ``speed * vmax`` to 0 in one simulation step."""
        i, t = pos
        return (i, 0.0) if t <= 0.0 or i >= len(self.segs) else (i + 1, 0.0)

    def elapsed_at(self, pos) -> float:
        """Time spent in the time step of ``pos`` when the robot is there."""
        i, t = pos
        if i >= len(self.segs):
            return 0.0
        step, spent = self.segs[i][3], t
        for k in range(i - 1, -1, -1):
            if self.segs[k][3] != step:
                return spent
            spent += self.segs[k][2]
        return spent + self.elapsed0
