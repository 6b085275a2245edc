"""The paper's comparisons (Tables I and II): every model variant on the same seeded scenarios.

Variants (the paper's rows): learned tool + learned environment landmark; learned tool + manual
(bowl); manual (hand-picked tip) + manual; arbitrary (gripper origin) + manual; and the learned
model followed with obstacles ignored. Each is trained once by ``lfd.train_cli.main`` (the
``lfd-train`` / ``train.py`` command, called in this process; missing ones are trained on
demand) into ``<models>/<tool>-<env>/``. Scenarios run in parallel worker processes,
each with its own PyBullet client; finished runs are appended to ``runs.jsonl`` at once, so an
interrupted evaluation resumes where it stopped. Each run's task-point path (the model's tool
point in the world frame as executed) is saved beside it, in
``paths/<variant>_<latency>_<scenario>.npy``. The world runs on while the planner works
(``sim.execute``, ``EvalSettings.latency``: the wall-clock time of each plan by default).
"""

from __future__ import annotations

import json
import math
import shlex
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lfd.cli import USER_ERRORS, error_line
from lfd.train_cli import main as train_main
from sim.execute import parse_latency
from sim.scenarios import Scenario, draw_scenarios

__all__ = ["VARIANTS", "EvalSettings", "TrainingFailed", "Variant", "evaluate", "format_table", "run_one"]

# how the executor times a plan (``sim.execute.ExecSettings.pace``), logged with every run: runs
# logged without it were paced per visited step (before ``lfd.timing.step_clock``) and are redone
EXEC_PACE = "demonstrated"


class TrainingFailed(RuntimeError):
    """The training command could not make a variant's model (the message gives its reason);
    ``returncode`` is its exit status (2: bad input, such as broken demonstrations; 130 / 143:
    interrupted)."""

    def __init__(self, message: str, returncode: int):
        super().__init__(message)
        self.returncode = returncode


@dataclass(frozen=True)
class Variant:
    name: str
    tool: str           # FitConfig.tool: learn | tip | gripper (train.py --tool learned | manual | arbitrary)
    env: str            # FitConfig.env: learn | bowl (train.py --env learned | manual)
    obstacles: bool = True
    label_tool: str = ""
    label_env: str = ""

    @property
    def model_key(self) -> str:
        return f"{self.tool}-{self.env}"


VARIANTS = (
    Variant("learned+learned", "learn", "learn", True, "Learned", "Learned"),
    Variant("learned+manual", "learn", "bowl", True, "Learned", "Manual"),
    Variant("manual+manual", "tip", "bowl", True, "Manual", "Manual"),
    Variant("arbitrary+manual", "gripper", "bowl", True, "Arbitrary", "Manual"),
    Variant("no-obstacle-avoidance", "learn", "learn", False, "(No obstacle", "avoidance)"),
)


@dataclass(frozen=True)
class EvalSettings:
    """roadmap_size: PRM* vertices per scenario (None: ``lfd.planning.task_planner.default_vertices`` of
    each model's time steps); seed: base seed of the scenario set;
    n_scenarios; workers: processes; video: write a GIF of the first scenario per variant;
    latency: simulated time a plan costs (``sim.execute.ExecSettings.latency``: "measured",
    "none" or seconds)."""

    task: str = "powder"
    n_scenarios: int = 10
    seed: int = 0
    roadmap_size: int | None = None
    workers: int = 2
    video: bool = False
    variants: tuple = tuple(v.name for v in VARIANTS)
    latency: str = "measured"

    def __post_init__(self):
        object.__setattr__(self, "latency", str(parse_latency(self.latency)))


def planner_settings(roadmap_size: int | None, seed: int, task: str, tool_point):
    """The ``TaskPlannerSettings`` of an evaluation run (and of ``plan.py``'s single plans): the
    sweep margin of the task's tool around the model's tool point (``sim.collision.sweep_margin``)."""
    from lfd.planning.planner import PlannerSettings
    from lfd.planning.task_planner import TaskPlannerSettings
    from sim.collision import sweep_margin
    margin = sweep_margin(task, tool_point.detach().cpu().numpy())
    return TaskPlannerSettings(n_vertices=roadmap_size, seed=seed, planner=PlannerSettings(sweep_margin=margin))


def model_dir_for(models: Path, v: Variant) -> Path:
    return models / v.model_key


def ensure_model(task: str, models: Path, demos: Path | None, v: Variant, train_seed: int = 0) -> Path:
    """Train the variant's model with ``lfd.train_cli.main`` (in this process) unless it exists;
    ``TrainingFailed`` when it cannot.

    ``train_seed`` seeds the learner (and the demonstrations, when ``demos`` is None and the
    training has to make them in ``./runs/demos/<task>``). It is not the scenario set's base
    seed: a model is trained once and evaluated on any scenario set, so that tables of different
    base seeds compare the same models."""
    out = model_dir_for(models, v)
    if (out / "model.pt").is_file() and (out / "config.json").is_file():
        return out
    argv = ["--task", task, "--tool", v.tool, "--env", v.env, "--out", str(out), "--seed", str(train_seed)]
    if demos is not None:
        argv += ["--demos", str(demos)]
    print(f"[evaluate] training {v.model_key}: lfd-train {shlex.join(argv)}", file=sys.stderr, flush=True)
    what = f"training the {v.name} model ({v.model_key})"
    try:
        code = train_main(argv)
    except USER_ERRORS() as e:  # bad demonstrations, every restart failing, ...: its reason, one line
        raise TrainingFailed(f"{what} failed with exit status 2: {error_line(e)}", 2) from e
    if code:
        raise TrainingFailed(f"{what} stopped with exit status {code}", code)
    return out


def _init_worker() -> None:
    """First thing in each forked evaluation worker: one torch thread. This process may have run
    torch's thread pool (a model trained in-process by ``ensure_model``, demonstrations made by
    ``sim.demo_job``), and a forked child that starts a parallel region of that pool's OpenMP
    waits forever for threads it does not have."""
    import torch
    torch.set_num_threads(1)


def run_one(task: str, scenario: Scenario, variant: Variant, model_dir: str, roadmap_size: int | None,
            video_path: str | None = None, with_path: bool = False, latency: str = "measured") -> dict:
    """One scenario with one variant, in this process. Returns a JSON-ready dict."""
    import torch

    from lfd.learning.model import TaskModel
    from lfd.planning.task_planner import TaskPlanner
    from lfd.robot.kinematics import KinematicModel
    from sim.collision import make_collision_fns
    from sim.execute import ExecSettings, execute_plan
    from sim.world import World

    torch.set_num_threads(1)
    tic = time.perf_counter()
    model = TaskModel.load(model_dir)
    model.kin = KinematicModel.from_spec(model.robot, dtype=model.dtype)
    with World(task, scenario=scenario.placements) as world:
        fns = make_collision_fns(world, obstacles=variant.obstacles)
        planner = TaskPlanner(model, fns.collision_fn, fns.segment_fn,
                              batch_collision_fn=fns.batch_collision_fn,
                              settings=planner_settings(roadmap_size, scenario.seed, task, model.tool))
        frames = [] if video_path else None
        res = execute_plan(world, planner, scenario,
                           ExecSettings(pace=EXEC_PACE, frame_every=48 if video_path else 0, latency=latency),
                           frames=frames)
        if video_path and frames:
            import imageio.v2 as imageio
            imageio.mimsave(video_path, frames[::2], duration=0.2, loop=0)
    out = res.to_dict(with_path=with_path)
    out.update(scenario=scenario.seed, variant=variant.name, wall_s=time.perf_counter() - tic,
               roadmap_size=planner.n_vertices, latency=str(latency), pace=EXEC_PACE,
               roadmap_vertices=planner.roadmap.n if planner.roadmap is not None else 0)
    return out


def save_path(out_dir: Path, row: dict, path) -> str:
    """Write a run's task-point path ``(P, 3)`` (world frame, m, one point every
    ``ExecSettings.record_every`` simulation steps) to ``paths/<variant>_<latency>_<scenario>.npy``
    under ``out_dir``; returns that name relative to ``out_dir`` (what ``runs.jsonl`` records).
    The latency mode is in the name because a log may keep runs of another setting, which are
    run again beside them (``evaluate``): each row keeps its own path."""
    rel = Path("paths") / f"{row['variant']}_{row.get('latency', 'none')}_{row['scenario']}.npy"
    (out_dir / rel).parent.mkdir(parents=True, exist_ok=True)
    np.save(out_dir / rel, np.asarray(path, dtype=np.float64).reshape(-1, 3))
    return rel.as_posix()


def _pct(values, q) -> float:
    return float(np.percentile(values, q)) if len(values) else math.nan


def _stats(values) -> dict:
    return {"median": _pct(values, 50), "p95": _pct(values, 95)}


def summarize(runs: list[dict], variant: Variant, learning_time_s: float) -> dict:
    """One variant's line of ``results.json``. Latencies, each ``{median, p95}`` in ms:
    ``initial_ms`` and ``replan_ms`` are the searches alone (the paper's planning latency);
    ``build_ms`` is the first landmark update (the roadmap's construction) before the first
    plan, ``improve_ms`` the anytime re-plans after a far move (the roadmap's growth and the
    search on it), and ``reaction_ms`` a re-plan's landmark update (new step costs, new biased vertices
    after a far move) plus its search: the time from sensing a move to holding the new plan.
    Runs logged before the update was timed have no ``build_ms``/``replan_update_ms`` and are
    left out of those two."""
    init = [r["initial_ms"] for r in runs if not math.isnan(r["initial_ms"])]
    rep = [x for r in runs for x in r["replan_ms"]]
    build = [r["build_ms"] for r in runs if not math.isnan(r.get("build_ms", math.nan))]
    react, improve = [], []
    for r in runs:
        if len(r.get("replan_update_ms", ())) != len(r["replan_ms"]):
            continue  # logged before the update was timed
        kinds = r.get("replan_kind") or ["move"] * len(r["replan_ms"])
        for kind, u, x in zip(kinds, r["replan_update_ms"], r["replan_ms"]):
            (react if kind == "move" else improve).append(u + x)
    return {
        "tool_landmark": variant.label_tool, "env_landmark": variant.label_env,
        "success_rate": float(np.mean([r["success"] for r in runs])) if runs else math.nan,
        "n_scenarios": len(runs),
        "collisions": int(sum(bool(r["contacts"]) for r in runs)),
        "mean_fraction_in_bowl": float(np.mean([r["fraction_in_bowl"] for r in runs])) if runs else math.nan,
        "learning_time_s": learning_time_s,
        "initial_ms": _stats(init), "replan_ms": _stats(rep),
        "build_ms": _stats(build), "reaction_ms": _stats(react), "improve_ms": _stats(improve),
        "latency_mode": sorted({r.get("latency", "none") for r in runs}),
        "tracking_max_mm": max([r["tracking_max_mm"] for r in runs if "tracking_max_mm" in r], default=math.nan),
        "scenarios": [{"scenario": r["scenario"], "success": r["success"], "reason": r["reason"],
                       "fraction_in_bowl": r["fraction_in_bowl"]} for r in sorted(runs, key=lambda r: r["scenario"])],
    }


def _strict_json(x):
    """``x`` with every NaN or infinite float as None: ``results.json`` is strict JSON (``null``
    where nothing was measured, e.g. no re-plans), readable by jq and JavaScript."""
    if isinstance(x, dict):
        return {k: _strict_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_strict_json(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _ms(stats: dict | None) -> str:
    """The median of ``{median, p95}`` in whole ms, '-' when missing or NaN."""
    x = (stats or {}).get("median", math.nan)
    return "-" if math.isnan(x) else f"{x:.0f}ms"


PAPER_LATENCY_MS = {"powder": 182, "pour": 200}  # the paper's planning latency (Tables I, II; 12 cores)


def format_table(results: dict, task: str, latency: str | None = None) -> str:
    """The paper's table: medians of the latencies (``summarize``); '-' where none was measured.
    ``latency``: the evaluation's latency mode, named under the table."""
    head = f"{'Tool landmark':<14} {'Environment landmark':<21} {'Success':>8} {'Learning':>9} " \
           f"{'Plan (init)':>12} {'Replan':>9} {'Reaction':>9}"
    n = max((v['n_scenarios'] for v in results.values()), default=0)
    lines = [f"{task}: success rate over {n} scenarios", head, "-" * len(head)]
    for v in results.values():
        lines.append(f"{v['tool_landmark']:<14} {v['env_landmark']:<21} {v['success_rate']:>8.0%} "
                     f"{v['learning_time_s']:>8.1f}s {_ms(v['initial_ms']):>12} {_ms(v['replan_ms']):>9} "
                     f"{_ms(v.get('reaction_ms')):>9}")
    lines.append("Plan and Replan: the search alone (the paper's latency); Reaction: a re-plan with the "
                 "landmark update before it (or the roadmap's growth, for the anytime re-plan after a far move); "
                 f"the paper: {PAPER_LATENCY_MS.get(task, '-')} ms on 12 cores")
    if latency is not None:
        lines.append(f"latency mode: {latency} (the simulated time each plan costs while the robot moves on)")
    return "\n".join(lines)


def evaluate(settings: EvalSettings, out_dir: Path, models: Path, demos: Path | None = None,
             progress=None) -> dict:
    """Run every variant on every scenario; write ``results.json``; return it."""
    by_name = {v.name: v for v in VARIANTS}
    unknown = [n for n in settings.variants if n not in by_name]
    if unknown:
        raise ValueError(f"unknown variant(s) {unknown}; known: {list(by_name)}")
    variants = [by_name[n] for n in settings.variants]
    out_dir.mkdir(parents=True, exist_ok=True)
    learn_s = {}
    for v in variants:
        md = ensure_model(settings.task, models, demos, v)
        summary = md / "summary.json"
        learn_s[v.name] = json.loads(summary.read_text()).get("learning_time_s", math.nan) \
            if summary.is_file() else math.nan
    scenarios = draw_scenarios(settings.task, settings.n_scenarios, settings.seed)
    log = out_dir / "runs.jsonl"
    done = {}
    text = log.read_text() if log.is_file() else ""
    if text:
        for line in text.splitlines():
            try:
                r = json.loads(line)
                # runs of another setting are redone: logged without a latency mode, a run was
                # made in a frozen world ("none"); with a dwell other than the paper's interval
                # (an option since removed), with other edge costs
                if (r.get("latency", "none") == settings.latency and r.get("dwell", "interval") == "interval"
                        and r.get("pace") == EXEC_PACE):
                    done[(r["variant"], r["scenario"])] = r
            except (ValueError, KeyError):
                continue  # a line cut by an interruption
    jobs = []
    for v in variants:
        for i, sc in enumerate(scenarios):
            if (v.name, sc.seed) in done:
                continue
            video = str(out_dir / f"{settings.task}_{v.name}_scenario{sc.seed}.gif") \
                if settings.video and i == 0 else None
            jobs.append((settings.task, sc, v, str(model_dir_for(models, v)), settings.roadmap_size, video,
                         True, settings.latency))
    total = len(variants) * len(scenarios)
    bar = progress(total=total, initial=total - len(jobs)) if progress else None
    with log.open("a") as fh:
        if text and not text.endswith("\n"):
            fh.write("\n")  # the last line was cut by a kill: new runs start their own line

        def record(r: dict) -> None:
            """Log one finished run at once; its task-point path goes to its own file."""
            path = r.pop("task_point_path", None)
            if path is not None:
                r["task_point_path"] = save_path(out_dir, r, path)
            fh.write(json.dumps(r) + "\n")
            fh.flush()
            done[(r["variant"], r["scenario"])] = r
            if bar:
                bar.update(1)

        if settings.workers <= 1:
            for job in jobs:
                record(run_one(*job))
        else:
            with ProcessPoolExecutor(max_workers=settings.workers, initializer=_init_worker) as pool:
                futures = [pool.submit(run_one, *job) for job in jobs]
                for f in as_completed(futures):
                    record(f.result())
    if bar:
        bar.close()
    seeds = {sc.seed for sc in scenarios}
    results = {v.name: summarize([r for (n, s), r in done.items() if n == v.name and s in seeds], v,
                                 learn_s[v.name]) for v in variants}
    payload = {"task": settings.task, "base_seed": settings.seed, "n_scenarios": settings.n_scenarios,
               "roadmap_size": settings.roadmap_size, "latency": settings.latency,
               "models": {v.name: str(model_dir_for(models, v)) for v in variants}, "variants": results,
               "scenario_set": [sc.to_dict() for sc in scenarios]}
    tmp = out_dir / "results.json.tmp"
    tmp.write_text(json.dumps(_strict_json(payload), indent=2, allow_nan=False) + "\n")
    tmp.replace(out_dir / "results.json")
    return payload


def plan_scenario(model_dir: Path, scenario: Scenario, roadmap_size: int | None, gui: bool = False,
                  execute: bool = False, progress=None, latency: str = "measured") -> tuple[dict, object, object]:
    """Build the roadmap in the scenario's world, plan once from home (and optionally execute).

    Returns ``(report, plan_result, model)``.
    """
    from lfd.learning.model import TaskModel
    from lfd.planning.task_planner import TaskPlanner
    from lfd.robot.kinematics import KinematicModel
    from sim import layout as L
    from sim.collision import make_collision_fns
    from sim.execute import ExecSettings, execute_plan
    from sim.world import World

    model = TaskModel.load(model_dir)
    model.kin = KinematicModel.from_spec(model.robot, dtype=model.dtype)
    report = {"scenario": scenario.to_dict(), "latency": str(latency)}
    with World(scenario.task, gui=gui, scenario=scenario.placements) as world:
        fns = make_collision_fns(world, obstacles=True)
        tic = time.perf_counter()
        planner = TaskPlanner(model, fns.collision_fn, fns.segment_fn,
                              batch_collision_fn=fns.batch_collision_fn,
                              settings=planner_settings(roadmap_size, scenario.seed, scenario.task, model.tool))
        names, poses = world.sensed_landmarks()
        planner.update_landmarks(names, poses)
        report["roadmap_build_s"] = time.perf_counter() - tic
        res = planner.plan(L.HOME_Q, 0)
        report.update(status=res.status, message=res.message, cost=res.cost,
                      waypoints=len(res.configurations), latency_ms=res.latency_s * 1e3,
                      edges_evaluated=res.n_edges_evaluated, roadmap_vertices=planner.roadmap.n)
        if execute and res.ok:
            run = execute_plan(world, planner, scenario, ExecSettings(latency=latency))
            report["execution"] = run.to_dict()
    return report, res, model
