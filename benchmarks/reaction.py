"""Reaction benchmark on the real task: the learned model in PyBullet scenes, the bowl moved mid-task.

For each of N seeded scenarios (``sim.scenarios.draw_scenarios``, the evaluation's scenes) of a
task: build the planner's roadmap in the scene (``build_s``, reported apart), plan from home
(``initial``), then move the bowl to the scenario's second place (the powder's scenes have one;
the pour's get one, ``sim.scenarios.with_bowl_move``) while the robot is where that plan has it
at the move's time step, and time the reaction: the landmark update (new costs
stale, moved-object regions, no regrowth: ``TaskPlanner.update_landmarks(grow=False)``) plus the
search from that state (``reaction``). The first round of the biased regrowth for the new place
and the plan after it (the anytime improvement, off the critical path) are timed too
(``improve``), and the whole regrowth, a round at a time (``growth_s``). Each plan
reports its parts: landmark update, edge costs, cost-to-go, search, collision checks, number of
searches and heuristics, expanded nodes. Wall-clock seconds, one process, torch single-threaded.

Writes ``runs/bench/reaction.json``: ``tasks.<task>.reaction_s`` and ``initial_s`` (each
``{median, p95, mean}`` over scenes), ``improve_s``, ``growth_s``, ``build_s``, and every scene's plans.

    .venv/bin/python benchmarks/reaction.py [--task powder|pour] [--scenes 50] [--seed 0]
        [--models runs/<task>/models] [--roadmap-size N]

A missing learned model is trained first (``sim.evaluate.ensure_model``, learning seed 0).
"""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import numpy as np
import torch

from lfd.cli import ArgumentParser, run_main

ROOT = Path(__file__).resolve().parent.parent
PARTS = ("cost_s", "heuristic_s", "search_s", "collision_s", "searches", "heuristics", "expanded",
         "segment_checks", "blocked")


def _plan_row(res, update_s: float = 0.0) -> dict:
    row = {"status": res.status, "total_s": update_s + res.latency_s, "update_s": update_s,
           "plan_s": res.latency_s, "edges_costed": res.n_edges_evaluated}
    row.update({k: res.stats.get(k) for k in PARTS})
    return row


def _found_s(row: dict, key: str = "total_s"):
    """``row[key]`` (s) of a plan that was found, else None (not a planning latency)."""
    return row.get(key) if row.get("status") == "ok" else None


def _summary(values) -> dict:
    """``sim.report.stats`` of the scenes' ``values`` that were measured, and their number."""
    from sim.report import measured, stats

    return {**stats(values), "n": len(measured(values))}


def bench_scene(model, task: str, scenario, roadmap_size: int | None = None) -> dict:
    """One scene: build, initial plan, bowl move and reaction, growth and improved plan
    (``roadmap_size``: the roadmap's vertices, None for the task's default)."""
    from sim import layout as L
    from sim.collision import make_collision_fns
    from sim.runner import scene_planner
    from sim.world import World

    with World(task, scenario=scenario.placements, n_particles=0) as world:
        fns = make_collision_fns(world, obstacles=True)
        planner = scene_planner(model, fns, task, roadmap_size, scenario.seed)
        names, poses = world.sensed_landmarks()
        tic = time.perf_counter()
        planner.update_landmarks(names, poses)
        out = {"scenario": scenario.seed, "build_s": time.perf_counter() - tic,
               "vertices": planner.roadmap.n}
        first = planner.plan(L.HOME_Q, 0)
        out["initial"] = _plan_row(first)
        if not first.ok or scenario.bowl_after is None:
            return out
        # where the first plan has the robot when the bowl moves (the executor's sensing instant)
        i = int(np.searchsorted(first.time_steps, scenario.move_step(model.time_steps)))
        i = min(i, len(first.time_steps) - 1)
        q, t = first.configurations[i], int(first.time_steps[i])
        world.move_object("bowl", scenario.bowl_after)
        names, poses = world.sensed_landmarks()
        tic = time.perf_counter()
        planner.update_landmarks(names, poses, grow=False)
        update_s = time.perf_counter() - tic
        out["reaction"] = _plan_row(planner.plan(q, t), update_s)
        tic = time.perf_counter()
        grew = planner.grow(rounds=1)
        grow_s = time.perf_counter() - tic
        if grew:
            out["improve"] = _plan_row(planner.plan(q, t), grow_s)
            tic = time.perf_counter()
            rounds = 1
            while planner.growth_pending:
                planner.grow(rounds=1)
                rounds += 1
            out["growth_s"] = grow_s + time.perf_counter() - tic
            out["growth_rounds"] = rounds
            out["vertices_after_growth"] = planner.roadmap.n
    return out


def main(argv=None) -> int:
    ap = ArgumentParser(prog="benchmarks/reaction.py", description=__doc__.splitlines()[0])
    ap.add_argument("--task", choices=("powder", "pour"), default="powder")
    ap.add_argument("--scenes", type=int, default=50, help="scenarios (default 50)")
    ap.add_argument("--seed", type=int, default=0, help="base seed of the scenario set")
    ap.add_argument("--models", type=Path, default=None, help="trained variants (default runs/<task>/models)")
    ap.add_argument("--roadmap-size", type=int, default=None,
                    help="roadmap vertices (default: the planner's for the task's time steps, as lfd-plan)")
    ap.add_argument("--out", type=Path, default=ROOT / "runs" / "bench" / "reaction.json")
    args = ap.parse_args(argv)
    from sim.plan_cli import check_roadmap_size
    from sim.scenarios import check_set_size, draw_scenarios, with_bowl_move
    check_set_size(args.scenes, "--scenes")
    check_roadmap_size(args.roadmap_size)
    from lfd.learning.model import TaskModel
    from sim.evaluate import VARIANTS, ensure_model
    from sim.reach import DumpReach
    from sim.report import PAPER_LATENCY_MS, strict_json

    torch.set_num_threads(1)
    models = args.models or ROOT / "runs" / args.task / "models"
    model_dir = ensure_model(args.task, models, None, VARIANTS[0])
    model = TaskModel.load(model_dir)
    scenes = []
    with DumpReach(args.task) as reach:  # the pour's scenes keep the bowl still: give them a move
        drawn = [with_bowl_move(sc, reach) for sc in draw_scenarios(args.task, args.scenes, args.seed, reach)]
    for k, sc in enumerate(drawn):
        row = bench_scene(model, args.task, sc, args.roadmap_size)
        scenes.append(row)
        r = row.get("reaction", {})
        print(f"[{k + 1}/{args.scenes}] scenario {sc.seed}: build {row['build_s']:.1f} s, initial "
              f"{row['initial']['plan_s'] * 1e3:.0f} ms, reaction "
              f"{r.get('total_s', float('nan')) * 1e3:.0f} ms ({r.get('status', '-')})", flush=True)
    summary = {
        "model": str(model_dir), "n_scenes": len(scenes), "base_seed": args.seed, "roadmap_size": args.roadmap_size,
        # latencies of plans found (an answer without a plan, often at once, is none: sim.report.summarize too)
        "reaction_s": _summary([_found_s(s.get("reaction", {})) for s in scenes]),
        "initial_s": _summary([_found_s(s["initial"], "plan_s") for s in scenes]),
        "improve_s": _summary([_found_s(s.get("improve", {})) for s in scenes]),
        "growth_s": _summary([s.get("growth_s") for s in scenes]),
        "build_s": _summary([s["build_s"] for s in scenes]),
        "reaction_parts_median_s": {k: _summary([s.get("reaction", {}).get(k) for s in scenes])["median"]
                                    for k in ("update_s", "cost_s", "heuristic_s", "search_s", "collision_s")},
        "statuses": sorted({s.get("reaction", {}).get("status", "none") for s in scenes}),
        "scenes": scenes,
    }
    report = json.loads(args.out.read_text()) if args.out.is_file() else {}
    report.setdefault("tasks", {})[args.task] = summary
    report["machine"] = {"python": platform.python_version(), "torch": torch.__version__,
                         "cpu_threads": torch.get_num_threads(), "processor": platform.machine()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(strict_json(report), indent=2) + "\n")
    rs, ini = summary["reaction_s"], summary["initial_s"]
    print(f"{args.task}: reaction median {rs['median'] * 1e3:.0f} ms, mean {rs['mean'] * 1e3:.0f} ms, p95 "
          f"{rs['p95'] * 1e3:.0f} ms (paper: a mean of {PAPER_LATENCY_MS[args.task]} ms on 12 cores); initial plan "
          f"median {ini['median'] * 1e3:.0f} ms, p95 {ini['p95'] * 1e3:.0f} ms; roadmap build median "
          f"{summary['build_s']['median']:.1f} s")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    run_main(main, prog="benchmarks/reaction.py")
