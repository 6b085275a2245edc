"""Shared fixtures. Keep this small; simulator imports stay inside the fixtures."""

from __future__ import annotations

import os
import pickle

import pytest


def pytest_configure(config):
    """Under pytest-xdist (``make test``: a worker per core) each worker keeps torch to one
    thread: a core's worth of threads per worker would contend for the same cores."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        import torch

        torch.set_num_threads(1)


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
def powder_demos(tmp_path_factory):
    """5 simulated powder demonstrations (seed 21), drawn once per test run (each one is replayed
    with particles before it is kept: about a minute and a half on 2 cores): ``(folder, the .npz
    paths, the kept sim.demos.DemoAttempt objects)``. Tests read them, never change them. Under
    pytest-xdist (``make test`` runs on every core) the workers share one set: the first to need
    it draws it, under a file lock, into their common temporary folder."""
    from filelock import FileLock

    from lfd.learning.demos import demo_files
    from sim.demos import generate

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the run's folder, above each worker's own
    folder, kept_file = root / "powder_demos", root / "powder_demos_attempts.pkl"
    with FileLock(str(root / "powder_demos.lock")):
        if not kept_file.is_file():
            kept: list = []
            generate("powder", folder, n=5, seed=21, progress=False, keep_attempts=kept)
            kept_file.write_bytes(pickle.dumps(kept))
    return folder, demo_files(folder), pickle.loads(kept_file.read_bytes())


@pytest.fixture(scope="session")
def small_powder_model(tmp_path_factory, powder_demos):
    """A powder model learned from ``powder_demos`` (2 restarts): the folder holding ``model.pt``
    and ``config.json``. Shared by the end-to-end and the Ray sweep tests."""
    from lfd.learning.demos import load_demos
    from lfd.learning.learn import FitConfig, fit
    from lfd.robot.kinematics import KinematicModel

    ds = load_demos(powder_demos[0])
    res = fit(ds, KinematicModel.from_spec(ds.robot), FitConfig(restarts=2, seed=0))
    out = tmp_path_factory.mktemp("model")
    res.model.save(out)
    return out
