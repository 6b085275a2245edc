"""Soak test of closed-loop planning: many re-plans with random landmark moves, memory watched.

    python benchmarks/soak.py [--model runs/powder/models/learn-learn] [--replans 1000]
                              [--roadmap-size 1000] [--seed 0]

The learned model plans in a powder scenario's world (real collision checks); between re-plans the
bowl jumps to a random place in the 30-inch square, and every 50th move it leaves the table
(unreachable, far off to the side) and comes back, so the planner goes through 'no plan' and back.
Each re-plan starts from a configuration of the previous plan (the robot moving along), at its
time step. Reports the latency percentiles of the re-plans that found a plan (the landmark update,
which grows the roadmap after a far move, and the search; the search alone beside it), statuses,
and the process's resident memory after a warm-up of
``max(50, replans / 10)`` re-plans (the bounded caches and the capped roadmap fill up then) and
after the last re-plan; growth between the two must stay under 10%. The memory at the very start
is reported too. Writes runs/bench/soak.json.
"""

from __future__ import annotations

import gc
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from lfd.cli import ArgumentParser, UsageError, run_main, writable_dir


def rss_mb() -> float:
    """Resident set size of this process, MiB (Linux /proc)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def main(argv=None) -> int:
    ap = ArgumentParser(prog="benchmarks/soak.py", description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=ROOT / "runs" / "powder" / "models" / "learn-learn")
    ap.add_argument("--replans", type=int, default=1000)
    ap.add_argument("--roadmap-size", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=ROOT / "runs" / "bench")
    args = ap.parse_args(argv)
    if args.replans < 60:
        raise UsageError(f"--replans must be at least 60, got {args.replans}")
    from sim.plan_cli import check_roadmap_size
    check_roadmap_size(args.roadmap_size)
    if not (args.model / "model.pt").is_file():
        raise UsageError(f"--model {args.model}: no model.pt (train one: python train.py --task powder "
                         f"--out {args.model})")
    out = writable_dir(args.out)

    import torch

    from sim import layout as L
    from sim.collision import make_collision_fns
    from sim.model_check import load_checked_model
    from sim.runner import scene_planner
    from sim.scenarios import draw_scenario
    from sim.world import World

    torch.set_num_threads(1)
    rng = np.random.default_rng(args.seed)
    model, task = load_checked_model(args.model)  # its landmarks and robot are the scenario's
    scenario = draw_scenario(task, args.seed)
    lat, search, statuses, edges = [], [], {}, []
    with World(scenario.task, scenario=scenario.placements, n_particles=0) as world:
        fns = make_collision_fns(world)
        planner = scene_planner(model, fns, task, args.roadmap_size, args.seed)  # an evaluation run's planner
        names, poses = world.sensed_landmarks()
        bowl = names.index("bowl")
        planner.update_landmarks(names, poses)
        res = planner.plan(L.HOME_Q, 0)
        q, t = L.HOME_Q.copy(), 0
        gc.collect()
        rss_start = rss_mb()
        warmup = max(50, args.replans // 10)
        rss0 = None
        tic = time.perf_counter()
        for i in range(args.replans):
            if i == warmup:  # caches have filled to their bounds: growth from here on is a leak
                gc.collect()
                rss0 = rss_mb()
            poses = poses.copy()
            if i % 50 == 49:
                poses[bowl, :3, 3] = [0.2, 2.5, 0.0]          # off the table, out of reach
            else:
                c = np.asarray(L.SQUARE_CENTER_XY)
                poses[bowl, :2, 3] = c + rng.uniform(-L.SQUARE_HALF, L.SQUARE_HALF, 2)
                poses[bowl, 2, 3] = L.TABLE_TOP_Z + L.BOWL_HEIGHT / 2
            tac = time.perf_counter()
            planner.update_landmarks(names, poses)  # (the growth after a far move included)
            res = planner.plan(q, t)
            if res.ok:  # a re-plan's latency: the update and the search (an answer without a plan is none)
                lat.append((time.perf_counter() - tac) * 1e3)
                search.append(res.latency_s * 1e3)
            edges.append(res.n_edges_evaluated)
            statuses[res.status] = statuses.get(res.status, 0) + 1
            if res.ok and len(res.configurations) > 2:   # the robot moves along its plan
                k = int(rng.integers(1, min(4, len(res.configurations) - 1)))
                q, t = res.configurations[k], int(res.time_steps[k])
                if t >= model.time_steps - 2:
                    q, t = L.HOME_Q.copy(), 0
            if (i + 1) % 100 == 0:
                print(f"{i + 1}/{args.replans} replans, median {np.median(lat) if lat else float('nan'):.0f} ms, RSS {rss_mb():.0f} MiB",
                      flush=True)
        wall = time.perf_counter() - tic
        gc.collect()
        rss1 = rss_mb()
    def spread(x):
        x = np.asarray(x)
        return {"median": float(np.median(x)), "p90": float(np.percentile(x, 90)), "p95": float(np.percentile(x, 95)),
                "p99": float(np.percentile(x, 99)), "max": float(x.max())} if len(x) else None

    report = {
        "replans": args.replans, "roadmap_size": args.roadmap_size, "model": str(args.model),
        "latency_ms": spread(lat),  # the re-plans that found a plan: landmark update (growth) + search
        "search_ms": spread(search),  # their searches alone
        "edges_evaluated_median": float(np.median(edges)), "statuses": statuses,
        "rss_mb_start": rss_start, "warmup_replans": warmup, "rss_mb_before": rss0, "rss_mb_after": rss1, "rss_growth": (rss1 - rss0) / rss0, "wall_s": wall,
        "roadmap_vertices_final": planner.roadmap.n,
    }
    (out / "soak.json").write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report, indent=2))
    under = report["rss_growth"] < 0.10
    print(f"RSS growth {report['rss_growth']:+.1%} ({'under' if under else 'OVER'} 10%)")
    return 0 if under else 1


if __name__ == "__main__":
    run_main(main, prog="benchmarks/soak.py")
