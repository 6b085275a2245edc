"""Planning benchmark: roadmap build, first plan and closed-loop replanning latency.

A synthetic 7-DOF problem (Baxter's left-arm joint limits and velocity limits, T = 24 steps,
dt = 0.1 s): the step cost is a Gaussian nll per time step around means on a curve in joint space
(negative near the means, like the learned model), the "landmarks" a_hat are an offset of that
curve, and obstacles are a few spheres in joint space (segments checked every 0.05 rad).
A synthetic stand-in: it measures the planner's own work, not the real task's (collision checks
in PyBullet, the learned costs): for that, ``benchmarks/reaction.py``. For each roadmap size:
build (edges are checked lazily, on the paths), first plan, then two replanning scenarios of >= 20
landmark moves each:

* ``closed_loop``: after each move, replan from the robot's current state; between moves the robot
  advances one waypoint along its last plan (back to the start when the task is done);
* ``from_start``: after each move, replan from the start configuration at step 0 (the whole task
  ahead: the worst case).

Latency is wall time (``latency_s``) and process CPU time (``cpu_s``; the machine's 2 cores are
shared, so wall time depends on the load of other jobs). Writes runs/bench/planning.json.

    .venv/bin/python benchmarks/planning.py [--sizes 1000 5000] [--moves 30] [--seed 0]

torch runs single-threaded here (``torch.set_num_threads(1)``): on the 2 shared cores the
default thread pool made small step-cost batches ~10x slower.
"""

from __future__ import annotations

import json
import math
import platform
import time
from pathlib import Path

import numpy as np
import torch

from lfd.cli import ArgumentParser, UsageError, run_main, writable_dir
from lfd.planning.planner import ClosedLoopPlanner, PlannerSettings
from lfd.planning.roadmap import Roadmap, mixed_samples
from lfd.planning.stepcost import CallableStepCost
from sim.report import strict_json

ROOT = Path(__file__).resolve().parent.parent
LOWER = np.array([-1.70, -2.147, -3.05, -0.05, -3.059, -1.571, -3.059])
UPPER = np.array([1.70, 1.047, 3.05, 2.618, 3.059, 2.094, 3.059])
VMAX = np.array([1.5] * 4 + [4.0] * 3)
T, DT, SIGMA = 24, 0.1, 0.25


def make_world(rng):
    """Sphere obstacles in joint space: collision_fn, batch_collision_fn, segment_fn."""
    centers = rng.uniform(LOWER * 0.6, UPPER * 0.6, (4, 7))
    radius = 0.6

    def batch_collision_fn(Q):
        d2 = ((Q[:, None, :] - centers[None]) ** 2).sum(-1)
        return (d2 < radius ** 2).any(axis=1)

    def collision_fn(q):
        return bool(batch_collision_fn(np.asarray(q)[None])[0])

    def segment_fn(q1, q2, step=0.05):
        m = max(2, int(math.ceil(np.max(np.abs(q2 - q1)) / step)) + 1)
        return bool(batch_collision_fn(q1 + (q2 - q1) * np.linspace(0, 1, m)[:, None]).any())

    return collision_fn, batch_collision_fn, segment_fn


def gaussian_step_cost(curve: np.ndarray):
    """Factory a_hat (7,) offset -> step_nll (B, 7) -> (B, T) of Gaussians around curve + a_hat."""
    const = 7 * math.log(math.sqrt(2 * math.pi) * SIGMA)

    def factory(a_hat):
        mu = torch.as_tensor(curve + np.asarray(a_hat, dtype=float)[None])  # (T, 7)
        mu2 = (mu ** 2).sum(-1)

        def step_nll(Q):
            d2 = (Q ** 2).sum(-1, keepdim=True) - 2.0 * Q @ mu.T + mu2[None]
            return 0.5 * d2.clamp_min(0.0) / SIGMA ** 2 + const
        return step_nll
    return factory


def percentile(x, p):
    return float(np.percentile(np.asarray(x), p)) if len(x) else float("nan")


def replan_series(planner, first, moves: int, rng, closed_loop: bool, move_sigma: float) -> dict:
    """Move the landmarks ``moves`` times, replanning after each move; latency statistics."""
    a_hat = np.zeros(7)
    q0 = first.configurations[0]
    q, t, plan = q0, 0, first
    wall, cpu, stats, statuses = [], [], [], []
    for _ in range(moves):
        if closed_loop and plan.ok and len(plan.time_steps) > 1:  # follow one edge of the plan
            q, t = plan.configurations[1], int(plan.time_steps[1])
        if not closed_loop or t >= T - 1:
            q, t = q0, 0
        a_hat = a_hat + rng.normal(0, move_sigma, 7)  # the landmarks move (a random walk)
        planner.update_landmarks(a_hat)
        plan = planner.plan(q, t)
        wall.append(plan.latency_s)
        cpu.append(plan.stats.get("cpu_s", float("nan")))
        stats.append(plan.stats)
        statuses.append(plan.status)
    keys = ("edges_evaluated", "points_evaluated", "expanded", "segment_checks", "step_nll_calls")
    return {"moves": moves, "statuses": {s: statuses.count(s) for s in sorted(set(statuses))},
            "latency_median_s": percentile(wall, 50), "latency_p95_s": percentile(wall, 95),
            "cpu_median_s": percentile(cpu, 50), "cpu_p95_s": percentile(cpu, 95),
            **{f"{k}_median": percentile([s.get(k, 0) for s in stats], 50) for k in keys},
            "edges_evaluated_max": max(s.get("edges_evaluated", 0) for s in stats)}


def run_size(n: int, moves: int, seed: int, move_sigma: float) -> dict:
    rng = np.random.default_rng(seed)
    collision_fn, batch_collision_fn, segment_fn = make_world(rng)
    ends = rng.uniform(LOWER * 0.7, UPPER * 0.7, (2, 7))
    curve = ends[0] + (ends[1] - ends[0]) * np.linspace(0, 1, T)[:, None]
    sample_fn = (lambda m: rng.uniform(LOWER, UPPER, (m, 7)))
    # "IK of the per-step means": configurations near the curve, 20 % of the roadmap
    near_curve = curve[rng.integers(0, T, 4 * n)] + rng.normal(0, 2 * SIGMA, (4 * n, 7))
    near_curve = np.clip(near_curve, LOWER, UPPER)
    tic = time.perf_counter()
    samples = mixed_samples(sample_fn, 2 * n, near_curve, 0.2, rng)
    rm = Roadmap.build(lambda m: samples[:m] if m == 2 * n else sample_fn(m), n, collision_fn,
                       segment_fn, batch_collision_fn=batch_collision_fn)
    build_s = time.perf_counter() - tic
    out = {"n": rm.n, "k": rm.k(), "roadmap_edges": rm.graph.number_of_edges(),
           "build_lazy_s": build_s}

    lt = np.log(np.tile([0.3, 0.5, 0.2], (T, 1)))
    floor = 7 * math.log(math.sqrt(2 * math.pi) * SIGMA)  # the Gaussian nll's minimum
    planner = ClosedLoopPlanner(rm, CallableStepCost(gaussian_step_cost(curve), T, floor), -lt, DT, VMAX,
                                settings=PlannerSettings())
    planner.update_landmarks(np.zeros(7))
    q = curve[0].copy()
    while collision_fn(q):
        q = np.clip(q + rng.normal(0, 0.1, 7), LOWER, UPPER)
    first = planner.plan(q, 0)
    out["first_plan"] = {"status": first.status, "latency_s": first.latency_s,
                         "cost": first.cost, "waypoints": len(first.time_steps), **first.stats}
    out["closed_loop"] = replan_series(planner, first, moves, rng, True, move_sigma)
    out["from_start"] = replan_series(planner, first, moves, rng, False, move_sigma)
    return out


def main(argv=None) -> int:
    ap = ArgumentParser(prog="benchmarks/planning.py", description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 5000])
    ap.add_argument("--moves", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--move-sigma", type=float, default=0.05,
                    help="std (rad) per joint of each landmark move of the Gaussians' means")
    ap.add_argument("--out", type=Path, default=ROOT / "runs" / "bench" / "planning.json")
    args = ap.parse_args(argv)
    if args.moves < 20:
        raise UsageError(f"--moves must be at least 20, got {args.moves}")
    if min(args.sizes) < 10:
        raise UsageError(f"--sizes must each be at least 10 vertices, got {args.sizes}")
    if not (math.isfinite(args.move_sigma) and args.move_sigma > 0):
        raise UsageError(f"--move-sigma must be a positive number of radians, got {args.move_sigma}")
    if args.out.is_dir():
        raise UsageError(f"--out {args.out}: is a folder; give the JSON file to write")
    writable_dir(args.out.parent, what="--out's folder")
    torch.set_num_threads(1)
    report = {"setting": {"d": 7, "T": T, "dt": DT, "vmax": VMAX.tolist(), "sigma": SIGMA,
                          "obstacles": "4 spheres r=0.6 in joint space", "torch_threads": 1,
                          "move_sigma": args.move_sigma, "moves": args.moves, "seed": args.seed,
                          "machine": platform.processor() or platform.machine()},
              "targets_s": {"1000": 0.050, "5000": 0.200},
              "runs": [run_size(n, args.moves, args.seed, args.move_sigma)
                       for n in args.sizes]}
    try:
        args.out.write_text(json.dumps(strict_json(report), indent=2))  # (an unplanned cost: null, not Infinity)
    except OSError as e:
        raise UsageError(f"cannot write {args.out}: {e.strerror or e}") from e
    for r in report["runs"]:
        print(f"n={r['n']:5d} k={r['k']} build {r['build_lazy_s']:.2f}s "
              f"first plan {r['first_plan']['latency_s'] * 1e3:.0f} ms")
        for name in ("closed_loop", "from_start"):
            rp = r[name]
            print(f"  {name:11s} replan wall median {rp['latency_median_s'] * 1e3:.1f} ms "
                  f"p95 {rp['latency_p95_s'] * 1e3:.1f} ms | cpu median "
                  f"{rp['cpu_median_s'] * 1e3:.1f} ms p95 {rp['cpu_p95_s'] * 1e3:.1f} ms | "
                  f"edges {rp['edges_evaluated_median']:.0f} expanded {rp['expanded_median']:.0f} "
                  f"{rp['statuses']}")
    return 0


if __name__ == "__main__":
    run_main(main, prog="benchmarks/planning.py")
