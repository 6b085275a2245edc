"""Collision checks per second: single calls and the batched call, on uniform random configurations.

Usage: ``python benchmarks/collision.py [--task powder|pour] [--n 1000] [--runs 5] [--out PATH]``.
Measures both checkers of ``sim.collision`` (``shadow``, the default, and ``inplace``), prints
the medians and writes them (with every run) to ``runs/bench/collision.json``.
"""

from __future__ import annotations

import json
import platform
import statistics
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:  # run as a script: make the repository's packages importable
    sys.path.insert(0, str(REPO))

from lfd.cli import ArgumentParser, UsageError, run_main, writable_dir


@dataclass(frozen=True)
class CollisionBench:
    method: str
    task: str
    n_configs: int
    runs: int
    free_fraction: float
    single_per_s: float           # median over runs
    batch_per_s: float            # median over runs
    single_runs: tuple
    batch_runs: tuple
    machine: str


def run(task: str, n: int, runs: int, method: str = "shadow", seed: int = 0) -> CollisionBench:
    from sim.collision import make_collision_fns
    from sim.world import World

    with World(task, n_particles=0) as world:
        fns = make_collision_fns(world, method=method)
        info = [__import__("pybullet").getJointInfo(world.robot, j, physicsClientId=world.client)
                for j in world.arm_joints]
        lower, upper = np.array([i[8] for i in info]), np.array([i[9] for i in info])
        rng = np.random.default_rng(seed)
        single, batch, free = [], [], []
        for _ in range(runs):
            Q = rng.uniform(lower, upper, (n, len(lower)))  # (n, 7)
            t = time.perf_counter()
            hits = [fns.collision_fn(q) for q in Q]
            single.append(n / (time.perf_counter() - t))
            t = time.perf_counter()
            fns.batch_collision_fn(Q)
            batch.append(n / (time.perf_counter() - t))
            free.append(1.0 - float(np.mean(hits)))
    fns.close()
    return CollisionBench(method, task, n, runs, float(np.mean(free)), statistics.median(single), statistics.median(batch),
                          tuple(round(x, 1) for x in single), tuple(round(x, 1) for x in batch),
                          f"{platform.machine()} {platform.processor() or ''}".strip())


def main(argv=None) -> int:
    ap = ArgumentParser(prog="benchmarks/collision.py", description=__doc__.splitlines()[0])
    ap.add_argument("--task", default="powder", choices=("powder", "pour"))
    ap.add_argument("--n", type=int, default=1000, help="configurations per run")
    ap.add_argument("--runs", type=int, default=5, help="runs (the median is reported)")
    ap.add_argument("--out", default=str(REPO / "runs" / "bench" / "collision.json"))
    args = ap.parse_args(argv)
    if args.n < 1 or args.runs < 1:
        raise UsageError(f"--n and --runs must be at least 1, got {args.n} and {args.runs}")
    out = Path(args.out)
    if out.is_dir():
        raise UsageError(f"--out {out}: is a folder; give the JSON file to write")
    writable_dir(out.parent, what="--out's folder")
    results = []
    for method in ("shadow", "inplace"):
        res = run(args.task, args.n, args.runs, method)
        results.append(asdict(res))
        print(f"{method:8s} collision checks/s ({res.task}, {res.n_configs} uniform random configs, median of "
              f"{res.runs} runs, {100 * res.free_fraction:.0f}% free): single {res.single_per_s:,.0f}/s, "
              f"batched {res.batch_per_s:,.0f}/s")
    try:
        out.write_text(json.dumps({"default": "shadow", "results": results}, indent=2) + "\n")
    except OSError as e:
        raise UsageError(f"cannot write {out}: {e.strerror or e}") from e
    print(out)
    return 0


if __name__ == "__main__":
    run_main(main, prog="benchmarks/collision.py")
