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


@pytest.fixture(scope="session")
def small_powder_model(tmp_path_factory):
    """A powder model learned from 5 simulated demonstrations (2 restarts): the folder holding
    ``model.pt`` and ``config.json``. Shared by the end-to-end and the Ray sweep tests."""
    from lfd.learning.demos import load_demos
    from lfd.learning.learn import FitConfig, fit
    from lfd.robot.kinematics import KinematicModel
    from sim.demos import generate

    demos = tmp_path_factory.mktemp("demos")
    generate("powder", demos, n=5, seed=21, progress=False)
    ds = load_demos(demos)
    res = fit(ds, KinematicModel.from_spec(ds.robot), FitConfig(restarts=2, seed=0))
    out = tmp_path_factory.mktemp("model")
    res.model.save(out)
    return out
