"""How much simulated time a plan costs while the robot moves on (``ExecSettings.latency``):
``"measured"`` (the plan's wall-clock time), ``"none"`` (the world waits) or a fixed number of
seconds. Free of PyBullet, so that the command line checks it before the simulator loads."""

from __future__ import annotations

import math

__all__ = ["LATENCIES", "charged_s", "parse_latency"]

LATENCIES = ("measured", "none")


def parse_latency(value) -> str | float:
    """``"measured"``, ``"none"`` or a fixed latency in seconds (a number, or its text) >= 0."""
    if isinstance(value, str) and value in LATENCIES:
        return value
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"latency must be 'measured', 'none' or seconds >= 0, got {value!r}") from None
    if not (math.isfinite(x) and x >= 0):
        raise ValueError(f"latency must be 'measured', 'none' or seconds >= 0, got {value!r}")
    return x


def charged_s(mode, wall_s: float) -> float:
    """Simulated seconds a plan that took ``wall_s`` of wall-clock time is charged."""
    if mode == "measured":
        return wall_s
    if mode == "none":
        return 0.0
    return float(mode)
