"""Shared fixtures. Keep this small; simulator imports stay inside the fixtures."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def make_world():
    """A factory ``make_world(task="powder", **kwargs) -> sim.world.World``; every world it
    made is closed when the test module ends (share one world per module)."""
    from sim.world import World

    worlds = []

    def make(task: str = "powder", **kwargs):
        world = World(task, **kwargs)
        worlds.append(world)
        return world

    yield make
    for world in worlds:
        world.close()
