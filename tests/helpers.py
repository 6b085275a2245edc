"""Small helpers shared by several test modules (imported as ``helpers``; tests/ is on sys.path)."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np


def longest_stay(alignment) -> int:
    """The most consecutive samples an alignment ``(S,)`` keeps on one step."""
    return max(len(list(g)) for _, g in itertools.groupby(alignment))


def rewrite_npz(path: Path, **changes) -> None:
    """Rewrite one ``.npz`` with keys changed (``None`` deletes the key)."""
    with np.load(path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    for k, v in changes.items():
        if v is None:
            data.pop(k, None)
        else:
            data[k] = v
    path.unlink()
    np.savez(path, **data)


def box_world(lo, hi, step: float = 0.005):
    """A toy world with one axis-aligned box obstacle ``[lo, hi]``: ``(in_box, segment_hits_box)``,
    the segment checked every ``step``."""
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)

    def in_box(q) -> bool:
        return bool(np.all(q >= lo) and np.all(q <= hi))

    def segment_hits_box(q1, q2) -> bool:
        m = max(2, int(np.ceil(np.linalg.norm(q2 - q1) / step)) + 1)
        P = q1 + (q2 - q1) * np.linspace(0.0, 1.0, m)[:, None]
        return bool(np.any(np.all((P >= lo) & (P <= hi), axis=1)))

    return in_box, segment_hits_box


LANDMARK_NAMES = ("bowl", "marker_1", "marker_2")


def small_demoset(n: int = 2, samples: int = 30, seed: int = 0, ground_truth=None):
    """``n`` small valid demonstrations (random joints near a nominal pose, 3 landmarks)."""
    from lfd.learning.demoset import Demonstration, DemoSet
    from lfd.robot.robots import BAXTER_LEFT
    from lfd.learning.tasks import POWDER

    rng = np.random.default_rng(seed)
    demos = []
    for i in range(n):
        poses = np.tile(np.eye(4), (len(LANDMARK_NAMES), 1, 1))
        poses[:, :3, 3] = rng.uniform(-0.5, 0.5, (len(LANDMARK_NAMES), 3))
        q = np.array([0.0, -0.5, 0.0, 1.2, 0.0, 0.5, 0.0]) + 0.1 * rng.standard_normal((samples + i, 7))
        demos.append(Demonstration(q=q, dt=0.1, landmarks=poses, name=f"demo_{i:03d}"))
    return DemoSet(demos=tuple(demos), joint_names=BAXTER_LEFT.joint_names, landmark_names=LANDMARK_NAMES,
                   robot=BAXTER_LEFT, task=POWDER, ground_truth=ground_truth)


def synthetic_demo_dir(folder: Path, n_demos: int, time_steps: int, Z: int, samples_per_step) -> Path:
    """Write a small known-truth powder demonstration set (lfd.learning.synthetic, seed 1) into ``folder``."""
    from lfd.learning.demos import save_demos
    from lfd.robot.kinematics import KinematicModel
    from lfd.learning.synthetic import make_synthetic
    from lfd.learning.tasks import POWDER

    ds, _ = make_synthetic(KinematicModel.from_spec(), n_demos=n_demos, time_steps=time_steps, Z=Z, seed=1,
                           task=POWDER, samples_per_step=samples_per_step)
    save_demos(folder, ds)
    return folder


class CliResult:
    """What an entry point run in-process by ``run_cli`` did: ``returncode``, ``stdout``, ``stderr``
    (the fields of ``subprocess.CompletedProcess``)."""

    def __init__(self, returncode, stdout: str, stderr: str):
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


def run_cli(main, prog: str, argv, capsys) -> CliResult:
    """Run an entry point ``main(argv) -> int`` in this process as the command ``prog`` runs it
    (``lfd.cli.run_main``: user errors become one line on stderr and exit status 2); ``capsys``
    is the test's pytest fixture, which captures what it printed."""
    import pytest

    from lfd.cli import run_main

    capsys.readouterr()  # what the test printed before is not the command's
    with pytest.raises(SystemExit) as info:
        run_main(main, [str(a) for a in argv], prog=prog)
    out, err = capsys.readouterr()
    return CliResult(info.value.code, out, err)


def entry_point(name: str):
    """``(main, prog)`` of a command: ``train.py`` / ``plan.py`` (the repository's wrappers, with
    their own prog names) or ``python -m <module>`` (the module's ``main``)."""
    import functools
    import importlib

    if name in ("train.py", "plan.py"):
        module = {"train.py": "lfd.train_cli", "plan.py": "sim.plan_cli"}[name]
        return functools.partial(importlib.import_module(module).main, prog=name), name
    if name.startswith("python -m "):
        module = importlib.import_module(name.split()[-1])
        return getattr(module, "main", None) or module._main, name
    raise ValueError(f"unknown command {name!r}")
