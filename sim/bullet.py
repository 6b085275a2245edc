"""PyBullet, imported without the banner it writes to the C-level stderr ("pybullet build time:
..."): the ``sim`` modules take it from here (``from sim.bullet import p``), so importing ``sim``
alone (``lfd-plan --help``, ``require_pybullet``) does not load the simulator."""

from __future__ import annotations

from sim import quiet_stdio

with quiet_stdio():
    import pybullet as p

__all__ = ["p"]
