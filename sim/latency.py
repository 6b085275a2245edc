"""How much simulated time a plan costs while the robot moves on (``ExecSettings.latency``):
``"measured"`` (the plan's wall-clock time), ``"none"`` (the world waits) or a fixed number of
seconds. Free of PyBullet, so that the command line checks it before the simulator loads."""

from __future__ import annotations

import math

__all__ = ["LATENCIES", "MAX_LATENCY_S", "charged_s", "describe_latency", "parse_latency"]

LATENCIES = ("measured", "none")
MAX_LATENCY_S = 60.0  # a fixed latency longer than any task (the arm would hold that long for each plan)


def parse_latency(value) -> str | float:
    """``"measured"``, ``"none"`` or a fixed latency in seconds (a number, or its text) in
    ``[0, MAX_LATENCY_S]``."""
    if isinstance(value, str) and value in LATENCIES:
        return value
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"latency must be 'measured', 'none' or seconds >= 0, got {value!r}") from None
    if not (math.isfinite(x) and 0 <= x <= MAX_LATENCY_S):
        raise ValueError(f"latency must be 'measured', 'none' or seconds in [0, {MAX_LATENCY_S:g}] "
                         f"(a plan that takes longer than a task), got {value!r}")
    return x


def charged_s(mode, wall_s: float) -> float:
    """Simulated seconds a plan that took ``wall_s`` of wall-clock time is charged."""
    if mode == "measured":
        return wall_s
    if mode == "none":
        return 0.0
    return float(mode)


def describe_latency(mode) -> str:
    """What the latency mode ``mode`` charges, in words (under the evaluation's table)."""
    if mode == "measured":
        return "each plan costs its wall-clock time in simulated time, while the robot moves on"
    if mode == "none":
        return "the world waits for the planner: plans cost no simulated time"
    return f"each plan costs {float(mode):g} s of simulated time, while the robot moves on"
