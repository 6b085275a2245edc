"""Stand-ins for the minutes-long parts of an evaluation, importable by forked workers and by a
subprocess: scenario sets without PyBullet's reachability draw, a run that only sleeps and
answers deterministically from its (variant, scenario), and jobs that fail on purpose."""

from __future__ import annotations

import os
import time
from pathlib import Path

from sim.scenarios import SEED_STRIDE, Scenario

SLEEP_S = 0.15


def draw(task: str, n: int, base_seed: int = 0, reach=None) -> list[Scenario]:
    """``n`` scenarios of base seed ``base_seed`` with the real seeds and a placeholder scene."""
    return [Scenario(task=task, seed=base_seed * SEED_STRIDE + i, placements={"bowl": (0.8, 0.3)})
            for i in range(n)]


def outcome(variant: str, scenario: int) -> bool:
    """A deterministic success pattern that differs between variants and scenarios."""
    return (scenario * 7 + len(variant)) % 3 != 0


def run(task, scenario, variant, model_dir, roadmap_size, video_path=None, with_path=False, latency="measured"):
    """``sim.runner.run_one``'s signature and row keys; no simulation."""
    time.sleep(SLEEP_S)
    ok = outcome(variant.name, scenario.seed)
    row = {"variant": variant.name, "scenario": scenario.seed, "success": ok, "reason": "fake", "contacts": [],
           "fraction_in_bowl": 1.0 if ok else 0.25, "initial_ms": 5.0, "replan_ms": [1.0], "wall_s": 0.0,
           "roadmap_vertices": 10, "pace": "demonstrated", "latency": latency}
    if with_path:
        row["task_point_path"] = [[0.5, 0.1, 0.0], [0.6, 0.2, 0.1]]
    return row


def flaky(marker_dir: str, key: str, fail_times: int, how: str = "raise") -> str:
    """Fail the first ``fail_times`` calls with this ``key`` (counted in files under
    ``marker_dir``, so across processes), by raising or, with ``how="die"``, by killing the
    worker process; then return ``key``."""
    calls = Path(marker_dir) / f"{key}.calls"
    with calls.open("ab") as fh:  # one byte per call: appends from several processes do not collide
        fh.write(b".")
    n = calls.stat().st_size - 1  # calls before this one
    if n < fail_times:
        if how == "die":
            os._exit(3)  # as the kernel's OOM killer would end it: no exception, no cleanup
        raise RuntimeError(f"{key} failed on purpose\nsecond line")
    return key


def fake_train(calls: list):
    """A stand-in for ``lfd.train_cli.main`` that records its argv in ``calls`` and writes the two
    files ``ensure_model`` checks for into ``--out``."""
    def train(argv):
        calls.append(argv)
        out = Path(argv[argv.index("--out") + 1])
        out.mkdir(parents=True)
        (out / "model.pt").write_bytes(b"")
        (out / "config.json").write_text("{}")
        return 0
    return train


def sleeper(pid_dir: str, seconds: float) -> int:
    """Write this worker's pid into ``pid_dir``, then sleep ``seconds`` (a job still in flight)."""
    (Path(pid_dir) / f"{os.getpid()}.pid").write_text("")
    time.sleep(seconds)
    return os.getpid()
