"""Plan a learned task in a new scene, or evaluate every model variant on seeded scenarios.

    lfd-plan --model DIR [--scenario-seed S] [--roadmap-size N] [--latency L] [--gui] [--out DIR] [--plot]
    lfd-plan --evaluate --task powder|pour [--scenarios N] [--seed S | --seeds S,S,..] [--demo-seeds K,..]
             [--workers K] [--executor local|ray [--address ADDR]] [--resume] [--latency L] [--out DIR] [--video]

(``python plan.py`` is the same command.) Relative paths and the default output folders are
taken from the current working directory.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from pathlib import Path

from lfd.cli import ArgumentParser, UsageError, path_arg, resume_command, run_main, writable_dir
from sim import require_pybullet
from sim.scenarios import MAX_BASE_SEED, MAX_SCENARIO_SEED, check_set_size
from sim.sweep import EXECUTORS

__all__ = ["PROG", "build_parser", "cli", "main", "parse"]

PROG = "lfd-plan"
MAX_ROADMAP = 100_000  # vertices: the spatiotemporal product holds T times as many (1e14 filled the memory)


# Peak memory of a scene's planner, measured (``/usr/bin/time -v python plan.py --model M
# --roadmap-size N --latency none``, docs/EXPERIMENTS.md): about 1 GB, plus 0.011 MB per vertex
# and time step for the powder (24 steps: 1.1 GB at 1,940 vertices, 2.6 GB at 7,613), 0.018 MB
# for the pour's attitude features (48 steps: 2.3 GB at 1,683, 6.5 GB at 6,505).
BASE_MB, MB_PER_VERTEX_STEP = 1000.0, 0.02


def check_roadmap_size(n: int | None) -> None:
    """``UsageError`` unless ``--roadmap-size`` ``n`` is None (the planner's default) or in [10, ``MAX_ROADMAP``]."""
    if n is not None and not 10 <= n <= MAX_ROADMAP:
        raise UsageError(f"--roadmap-size must be in [10, {MAX_ROADMAP}], got {n}")


def available_mb() -> float | None:
    """Memory this machine can give a new process now (MiB; ``MemAvailable``, else the physical
    memory), None where neither can be read."""
    import os
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) / 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2 ** 20
    except (ValueError, OSError, AttributeError):
        return None


def check_roadmap_memory(n: int | None, time_steps: int, processes: int = 1, may_grow: bool = True) -> None:
    """``UsageError`` when ``processes`` roadmaps of ``n`` vertices (None: the default) for a
    ``time_steps``-step model cannot even be built in this machine's available memory (the
    kernel would kill the run without a word; the estimate: ``BASE_MB`` and ``MB_PER_VERTEX_STEP``).
    The growth after landmark moves may add up to twice as many vertices again (``GROWTH_CAP``):
    a note on stderr says so when that would not fit and the run ``may_grow`` (it executes), as
    runs grow less (one bowl move, measured on 50 scenes each of the powder and the pour: 1.2-1.8
    times the build)."""
    from lfd.planning.task_settings import GROWTH_CAP, default_vertices
    vertices = default_vertices(time_steps) if n is None else n

    def need_mb(v: int) -> float:
        return processes * (BASE_MB + MB_PER_VERTEX_STEP * v * time_steps)

    need, have = need_mb(vertices), available_mb()
    if may_grow and have is not None and need <= have < need_mb(GROWTH_CAP * vertices):
        print(f"note: the roadmap may grow after landmark moves to {GROWTH_CAP * vertices} vertices, about "
              f"{need_mb(GROWTH_CAP * vertices) / 1024:.1f} GB{' in all' if processes > 1 else ''}, more than the "
              f"{have / 1024:.1f} GB available; a run that grows that far may be stopped by the kernel",
              file=sys.stderr)
    if have is not None and need > have:
        each = f" ({need / processes / 1024:.0f} GB in each of {processes} workers)" if processes > 1 else ""
        what = f"--roadmap-size {n}" if n is not None else f"the default roadmap size ({vertices})"
        raise UsageError(f"{what}: a roadmap of {vertices} vertices for a {time_steps}-step model "
                         f"needs about {need / 1024:.0f} GB{each}, and this machine has {have / 1024:.0f} GB "
                         f"available; take fewer vertices{' or fewer --workers' if processes > 1 else ''}")


def _seed_list(text: str) -> tuple[int, ...]:
    """``"0,1,2"`` -> ``(0, 1, 2)``: distinct non-negative integers."""
    try:
        seeds = tuple(int(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    if not seeds or len(set(seeds)) != len(seeds) or min(seeds) < 0:
        raise argparse.ArgumentTypeError(f"expected distinct non-negative integers, got {text!r}")
    return seeds


# the options of one mode only: given in the other, they are refused rather than ignored
_SINGLE_ONLY = ("--model", "--scenario-seed", "--gui", "--execute", "--plot")
_EVALUATE_ONLY = ("--scenarios", "--seed", "--seeds", "--demo-seeds", "--workers", "--executor", "--address",
                  "--resume", "--variants", "--models", "--demos", "--move-bowl", "--video")


def build_parser(prog: str = PROG) -> ArgumentParser:
    """The parser of ``lfd-plan`` / ``plan.py`` (``prog``)."""
    from sim.evaluate import VARIANTS
    ap = ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0] + " Relative paths and the default "
                        "output folders are taken from the current working directory.")
    ap.add_argument("--model", type=path_arg, metavar="DIR",
                    help="model folder written by train.py, the one holding model.pt and config.json "
                         "(single-plan mode; default: none, give it or --evaluate)")
    ap.add_argument("--scenario-seed", type=int, default=0, metavar="S", help="which scenario to plan in")
    ap.add_argument("--roadmap-size", type=int, default=None, metavar="N",
                    help="PRM* vertices; refused when this machine's memory cannot hold them (default: 1000 per 24 "
                         "time steps of the model)")
    ap.add_argument("--latency", default="measured", metavar="measured|none|SECONDS",
                    help="simulated time each plan costs while the robot moves on: its wall-clock time "
                         "(default: measured), none (the world waits: deterministic), or a fixed number of seconds")
    ap.add_argument("--gui", action="store_true", help="watch in the PyBullet GUI")
    ap.add_argument("--execute", action="store_true", help="also execute the plan closed-loop")
    ap.add_argument("--plot", action="store_true", help="plot the plan against the learned means")
    ap.add_argument("--evaluate", action="store_true", help="run the paper's comparison tables")
    ap.add_argument("--task", choices=("powder", "pour"),
                    help="task to evaluate (default: none; required with --evaluate); with --model, the task the model must be of")
    ap.add_argument("--scenarios", type=int, default=10, metavar="N", help="scenarios per variant")
    seeds = ap.add_mutually_exclusive_group()
    seeds.add_argument("--seed", type=int, default=None, metavar="S", help="base seed of the scenario set (default: 0)")
    seeds.add_argument("--seeds", type=_seed_list, default=None, metavar="S,S,...",
                       help="several scenario sets, a sweep: the table shows mean and spread over them "
                            "(default: the one of --seed)")
    ap.add_argument("--demo-seeds", type=_seed_list, default=(0,), metavar="K,K,...",
                    help="demonstration draws to train and evaluate: 0 is --demos (or ./runs/demos/<task>), "
                         "k > 0 a set the simulator draws with seed k, so draws other than 0 are not taken "
                         "with --demos (default: 0)")
    ap.add_argument("--workers", type=int, default=2, metavar="K",
                    help="parallel processes (with --executor ray and no --address: the local Ray's CPUs)")
    ap.add_argument("--executor", choices=EXECUTORS, default="local",
                    help="where the runs go: local processes, or Ray tasks (pip install 'lfd-landmarks[ray]')")
    ap.add_argument("--address", default=None, metavar="ADDR",
                    help="a running Ray cluster (ray start --head prints it; default: start a local Ray)")
    ap.add_argument("--resume", action="store_true",
                    help="continue the evaluation logged in --out, skipping finished runs (default: a folder "
                         "that holds logged runs is refused)")
    ap.add_argument("--variants", nargs="+", default=None, metavar="TOOL+ENV",
                    help=f"subset of variants to run, tool and environment landmark as in train.py's --tool "
                         f"and --env (default: all of {', '.join(v.name for v in VARIANTS)})")
    ap.add_argument("--models", type=path_arg, default=None, metavar="DIR",
                    help="folder of trained variants, missing ones are trained into it "
                         "(default: ./runs/<task>/models)")
    ap.add_argument("--demos", type=path_arg, default=None, metavar="DIR",
                    help="demonstrations to train missing variants on (default: ./runs/demos/<task>, "
                         "generated when empty)")
    ap.add_argument("--move-bowl", action="store_true",
                    help="with --evaluate: move the bowl mid-task in every scenario, at a quarter of the task "
                         "(the pour's scenes keep it still otherwise; the powder's always move it)")
    ap.add_argument("--video", action="store_true", help="write a GIF of the first scenario of each variant")
    ap.add_argument("--out", type=path_arg, default=None, metavar="DIR",
                    help="output folder (default: ./runs/<task>/plans/<model folder's name>, or ./runs/<task>/eval with --evaluate)")
    return ap


def parse(argv=None, prog: str = PROG):
    """The options of ``argv`` (default ``sys.argv[1:]``), checked; ``UsageError`` (or argparse's
    exit 2) on bad input."""
    ap = build_parser(prog)
    args = ap.parse_args(argv)
    mode, other = ("--evaluate", _SINGLE_ONLY) if args.evaluate else ("one plan (--model)", _EVALUATE_ONLY)
    dests = {opt: opt[2:].replace("-", "_") for opt in other}
    ignored = [opt for opt, dest in dests.items() if getattr(args, dest) != ap.get_default(dest)]
    if ignored:  # an option of the other mode would be silently ignored
        raise UsageError(f"{', '.join(ignored)} {'is' if len(ignored) == 1 else 'are'} not for {mode}")
    from sim.latency import parse_latency
    try:
        args.latency = str(parse_latency(args.latency))
    except ValueError as e:
        raise UsageError(f"--latency: {e}") from None
    check_roadmap_size(args.roadmap_size)
    seed_opt = "--seed" if args.seeds is None else "--seeds"
    args.seeds = args.seeds or (0 if args.seed is None else args.seed,)
    for opt, seeds, top in (("--scenario-seed", (args.scenario_seed,), MAX_SCENARIO_SEED),
                            (seed_opt, args.seeds, MAX_BASE_SEED), ("--demo-seeds", args.demo_seeds, MAX_BASE_SEED)):
        if not all(0 <= seed < top for seed in seeds):
            raise UsageError(f"{opt} must be in [0, {top}), got {', '.join(map(str, seeds))}")
    if args.address and args.executor != "ray":
        raise UsageError("--address is for --executor ray")
    if args.demos is not None and any(args.demo_seeds):
        raise UsageError("--demo-seeds other than 0 are drawn by the simulator; they cannot be combined with --demos")
    if args.demos is not None and not args.demos.exists():
        raise UsageError(f"--demos {args.demos}: no such folder")
    if args.models is not None and args.models.exists() and not args.models.is_dir():
        raise UsageError(f"--models {args.models}: exists and is not a folder")
    if args.evaluate:
        if args.task is None:
            raise UsageError("--evaluate needs --task powder|pour")
        check_set_size(args.scenarios, "--scenarios")
        if args.workers < 1:
            raise UsageError(f"--workers must be at least 1, got {args.workers}")
    elif args.model is None:
        raise UsageError("give --model DIR to plan once, or --evaluate --task TASK")
    elif args.model.is_file() or (args.model.suffix in (".pt", ".json") and not args.model.is_dir()):
        folder = args.model.parent
        raise UsageError(f"--model {args.model}: pass the model's folder (the one holding model.pt and "
                         f"config.json), e.g. --model {folder}, not a file in it")
    return args


def main(argv=None, prog: str = PROG) -> int:
    """``lfd-plan`` / ``python plan.py``: 0 when every plan succeeded (with ``--execute``, and its
    execution; with ``--evaluate``, when no run crashed: a failed scene is a result), 1 otherwise; raises
    ``UsageError`` (and the other ``lfd.cli.USER_ERRORS``) on bad input."""
    args = parse(argv, prog=prog)
    require_pybullet()
    if args.evaluate:
        from lfd.learning.checkpoint import Interrupted, InterruptGuard
        from sim.evaluate import (
            VARIANTS,
            EvalSettings,
            TrainingFailed,
            check_models_folder,
            evaluate,
            format_table,
            model_dir_for,
        )
        from sim.model_check import check_models_for_task
        models = args.models or Path("runs") / args.task / "models"
        variants = tuple(args.variants) if args.variants else tuple(v.name for v in VARIANTS)
        unknown = [v for v in variants if v not in {x.name for x in VARIANTS}]
        if unknown:
            raise UsageError(f"--variants: unknown {unknown}; choose from {[v.name for v in VARIANTS]}")
        check_models_folder(models)
        steps = check_models_for_task([model_dir_for(models, v, k) for k in args.demo_seeds for v in VARIANTS
                                       if v.name in variants], args.task)
        if args.executor == "local":  # (Ray's workers have their own machines' memory)
            from lfd.learning.tasks import task_from_name
            trained_as = task_from_name(args.task).time_steps  # (what a model still to be trained gets)
            check_roadmap_memory(args.roadmap_size, max((trained_as if t is None else t for t in steps),
                                                        default=trained_as), args.workers)
        out = writable_dir(args.out or Path("runs") / args.task / "eval")
        try:
            from tqdm import tqdm as progress
        except ImportError:
            progress = None
        settings = EvalSettings(task=args.task, n_scenarios=args.scenarios, seeds=args.seeds,
                                demo_seeds=args.demo_seeds, roadmap_size=args.roadmap_size, workers=args.workers,
                                video=args.video, variants=variants, latency=args.latency,
                                executor=args.executor, address=args.address, move_bowl=args.move_bowl)
        tic = time.perf_counter()
        try:
            with InterruptGuard():  # SIGTERM as Ctrl-C: the workers are stopped, not left running
                payload = evaluate(settings, out, models, args.demos, progress, resume=args.resume)
        except TrainingFailed as e:  # the training's own reason is in the message; no traceback of ours
            if e.returncode in (130, 143):  # interrupted while training a variant: its checkpoint is kept
                print(f"{prog}: interrupted while training; go on with: {resume_command(argv, prog, PROG)}",
                      file=sys.stderr)
                return e.returncode
            print(f"{prog}: error: {e}", file=sys.stderr)
            return e.returncode if e.returncode == 2 else 1
        except Interrupted as e:
            print(f"{prog}: interrupted by {e.name}; the finished runs are in {out / 'runs.jsonl'}; go on with: "
                  f"{resume_command(argv, prog, PROG)}", file=sys.stderr)
            return e.exit_status
        print(format_table(payload["variants"], args.task, settings.latency,
                           cells=payload["spread"] if len(payload["cells"]) > 1 else None))
        print(f"wall time {time.perf_counter() - tic:.0f} s, executor {settings.executor}")
        print(f"results: {out / 'results.json'}")
        if payload["crashed"]:  # failures in the table, but with no result of their own
            print(f"{prog}: {len(payload['crashed'])} run(s) crashed twice (their errors: 'crashed' in "
                  f"{out / 'results.json'}); run the same command with --resume to run them again",
                  file=sys.stderr)
            return 1
        return 0

    from sim.model_check import load_checked_model
    from sim.runner import plan_scenario
    from sim.scenarios import draw_scenario
    from sim.world import no_display
    why = no_display() if args.gui else ""  # (a RuntimeError traceback after the model was loaded)
    if why:
        raise UsageError(f"--gui: {why}; plan without it (--plot draws the plan)")
    checked, task_name = load_checked_model(args.model, args.task)  # landmarks, robot, task: before any simulation
    check_roadmap_memory(args.roadmap_size, checked.time_steps, may_grow=args.execute)
    # (not into the model's folder, which may be shared; one folder per model, so that two do not overwrite)
    out = writable_dir(args.out or Path("runs") / task_name / "plans" / args.model.resolve().name)
    scenario = draw_scenario(task_name, args.scenario_seed)
    report, res, model = plan_scenario(args.model, scenario, args.roadmap_size, gui=args.gui,
                                       execute=args.execute, latency=args.latency)
    print(f"plan: {report['status']}  cost {report['cost']:.1f}  waypoints {report['waypoints']}  "
          f"latency {report['latency_ms']:.0f} ms  ({report['edges_evaluated']} edge costs evaluated, "
          f"roadmap of {report['roadmap_vertices']} vertices built in {report['roadmap_build_s']:.1f} s)")
    if not res.ok:  # why, and what was not done for want of a plan
        skipped = [what for what, asked in (("--execute", args.execute), ("--plot", args.plot)) if asked]
        print(f"no plan: {res.message or res.status}" + (f"; {' and '.join(skipped)} skipped" if skipped else ""))
    if "execution" in report:
        ex = report["execution"]
        print(f"execution: {'success' if ex['success'] else 'failure'} ({ex['reason']}); "
              f"{ex['fraction_in_bowl']:.0%} in the bowl, {ex['n_replans']} replans; the tool tilted "
              f"{ex['executed_tilt_deg']:.0f} deg at most (commanded {ex['planned_tilt_deg']:.0f})")
    import io

    import numpy as np

    from lfd.learning.checkpoint import atomic_write_bytes, atomic_write_text
    from sim.report import strict_json
    stem = out / f"plan_scenario{args.scenario_seed}"
    buf = io.BytesIO()  # (written whole or not at all: a full disk left a truncated .npz)
    np.savez(buf, configurations=res.configurations, time_steps=res.time_steps, dt=model.task.dt, cost=res.cost)
    atomic_write_bytes(stem.with_suffix(".npz"), buf.getvalue())
    atomic_write_text(stem.with_suffix(".json"),  # (strict JSON: no plan's cost of inf is null)
                      json.dumps(strict_json(report), indent=2, default=float, allow_nan=False) + "\n")
    print(f"saved {stem.with_suffix('.npz')} and {stem.with_suffix('.json')}")
    if args.plot and res.ok:
        from lfd.plots import plot_plan_features
        from sim.world import World
        with World(task_name, scenario=scenario.placements) as w:
            names, poses = w.sensed_landmarks()
        png = plot_plan_features(model, res.configurations, res.time_steps,
                                 model.select_landmarks(names, poses), stem.with_suffix(".png"))
        print(f"plot: {png}")
    executed = report.get("execution", {}).get("success", True)
    return 0 if res.ok and executed else 1


def cli() -> None:
    """The ``lfd-plan`` console script."""
    run_main(main, prog=PROG)


if __name__ == "__main__":
    run_main(functools.partial(main, prog=PROG), prog=PROG)
