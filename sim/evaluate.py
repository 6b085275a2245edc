"""The paper's comparisons (Tables I and II): every model variant on the same seeded scenarios.

Variants (the paper's rows): learned tool + learned environment landmark; learned tool + manual
(bowl); manual (hand-picked tip) + manual; arbitrary (gripper origin) + manual; and the learned
model followed with obstacles ignored. Each is trained once by ``lfd.train_cli.main`` (the
``lfd-train`` / ``train.py`` command, called in this process; missing ones are trained on
demand) into ``<models>/<tool>-<env>/``.

A sweep runs a grid of *cells*: scenario sets (base seeds, ``EvalSettings.seeds``) times
demonstration draws (``demo_seeds``: draw k > 0 is made by the simulator with seed k into
``./runs/demos/<task>-seed<k>`` and its models are trained into ``<models>/demos-seed<k>/``; draw
0 uses the given demonstrations and models). Every (variant, draw, scenario) is one job, run
where ``EvalSettings.executor`` says (``sim.sweep``: local processes, or Ray tasks that receive
the model files through Ray's object store and rebuild their PyBullet world). Each finished run
is appended to ``runs.jsonl`` at once (a job that raises twice is logged with its error), so an
interrupted sweep loses only the runs in flight and ``resume=True`` (``--resume``) skips what is
done; ``results.json`` and the table are rebuilt from the log. Each run's task-point path (the
model's tool point in the world frame as executed) is saved beside it, in
``paths/<variant>[_demos<k>]_<latency>_<scenario>.npy``. The world runs on while the planner
works (``sim.execute``, ``EvalSettings.latency``: the wall-clock time of each plan by default).
"""

from __future__ import annotations

import json
import math
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lfd.cli import USER_ERRORS, UsageError, error_line
from lfd.learning.checkpoint import checkpoint_path, read_json
from lfd.learning.demos import load_demos, set_folder
from lfd.train_cli import default_demos, ensure_demos
from lfd.train_cli import main as train_main
from sim.attitude import demo_tilt
from sim.latency import parse_latency
from sim.model_check import MODEL_FILES, is_trained
from sim.reach import DumpReach
from sim.report import format_table, spread, strict_json, summarize
from sim.runlog import read_log, run_settings_of, save_path
from sim.runner import EXEC_PACE, init_worker, model_files, run_one, run_one_shipped
from sim.scenarios import MAX_BASE_SEED, check_set_size, draw_scenarios, with_bowl_move
from sim.sweep import EXECUTORS, Job, make_executor, require_ray, run_jobs

__all__ = ["VARIANTS", "EvalSettings", "TrainingFailed", "Variant", "check_models_folder", "evaluate", "format_table", "run_one"]

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
    """task; n_scenarios: scenarios per scenario set; seeds: base seeds of the scenario sets;
    demo_seeds: demonstration draws (0: the given demonstrations and models; k > 0: drawn by the
    simulator with seed k, see the module's docstring); roadmap_size: PRM* vertices per scenario
    (None: ``lfd.planning.task_settings.default_vertices`` of each model's time steps); workers:
    local processes, or the CPUs of a Ray started for the run; video: write a GIF of the first
    scenario per variant; variants: names from ``VARIANTS``; latency: simulated time a plan costs
    (``sim.execute.ExecSettings.latency``: "measured", "none" or seconds); executor: "local" or
    "ray" (``sim.sweep``); address: a running Ray cluster's (``ray start --head``), None to
    start a local Ray; move_bowl: give every scenario that has none a mid-task bowl move
    (``sim.scenarios.with_bowl_move``, at a quarter of the models' time steps; the pour's scenes
    keep the bowl still otherwise, the powder's always move it)."""

    task: str = "powder"
    n_scenarios: int = 10
    seeds: tuple[int, ...] = (0,)
    demo_seeds: tuple[int, ...] = (0,)
    roadmap_size: int | None = None
    workers: int = 2
    video: bool = False
    variants: tuple = tuple(v.name for v in VARIANTS)
    latency: str = "measured"
    executor: str = "local"
    address: str | None = None
    move_bowl: bool = False

    def __post_init__(self):
        object.__setattr__(self, "latency", str(parse_latency(self.latency)))
        for name in ("seeds", "demo_seeds"):
            values = tuple(int(x) for x in getattr(self, name))
            if not values or len(set(values)) != len(values) or not all(0 <= x < MAX_BASE_SEED for x in values):
                raise ValueError(f"{name} must be distinct integers in [0, {MAX_BASE_SEED}), got {values}")
            object.__setattr__(self, name, values)
        check_set_size(self.n_scenarios, "n_scenarios")
        if self.workers < 1:
            raise ValueError(f"workers must be at least 1, got {self.workers}")
        if self.executor not in EXECUTORS:
            raise ValueError(f"executor must be one of {EXECUTORS}, got {self.executor!r}")
        if self.address and self.executor != "ray":
            raise ValueError("an address is for the ray executor")
        known = {v.name for v in VARIANTS}
        unknown = [n for n in self.variants if n not in known]
        if unknown:
            raise ValueError(f"unknown variant(s) {unknown}; known: {sorted(known)}")


def models_for(models: Path, demo_seed: int = 0) -> Path:
    """The folder of the variants trained on demonstration draw ``demo_seed`` (0: ``models``)."""
    return models if demo_seed == 0 else models / f"demos-seed{demo_seed}"


def demos_for(task: str, demos: Path | None, demo_seed: int = 0) -> Path | None:
    """The demonstrations of draw ``demo_seed``: ``demos`` for 0 (None: ``lfd-train``'s default),
    ``./runs/demos/<task>-seed<k>`` for k > 0."""
    if demo_seed == 0:
        return demos
    if demos is not None:
        raise UsageError("demonstration draws other than 0 are made by the simulator; they cannot be "
                         f"combined with --demos {demos}")
    return Path("runs") / "demos" / f"{task}-seed{demo_seed}"


def model_dir_for(models: Path, v: Variant, demo_seed: int = 0) -> Path:
    return models_for(models, demo_seed) / v.model_key


def check_models_folder(models: Path) -> None:
    """``UsageError`` when ``models`` is one model's own folder, not the folder of the variants'
    models (a new model was trained inside it, without a word)."""
    if any((Path(models) / name).is_file() for name in MODEL_FILES):
        raise UsageError(f"--models {models}: a model's own folder (it holds model.pt or config.json); --models takes "
                         f"the folder of the variants' models ({', '.join(sorted({v.model_key for v in VARIANTS}))}), "
                         f"--model plans with one model")


def ensure_model(task: str, models: Path, demos: Path | None, v: Variant, train_seed: int = 0,
                 demo_seed: int = 0) -> Path:
    """Train the variant's model of demonstration draw ``demo_seed`` with ``lfd.train_cli.main``
    (in this process) unless it exists; ``TrainingFailed`` when it cannot.

    ``train_seed`` seeds the learner (and the demonstrations of draw 0, when ``demos`` is None and
    the training has to make them in ``./runs/demos/<task>``). It is not the scenario set's base
    seed: a model is trained once and evaluated on any scenario set, so that tables of different
    base seeds compare the same models. Draw k > 0 is generated here (seed k) when missing."""
    out = model_dir_for(models, v, demo_seed)
    if is_trained(out):
        return out
    demos = demos_for(task, demos, demo_seed)
    if demo_seed:
        assert demos is not None  # demos_for names the draw's folder
        ensure_demos(task, demos, demo_seed)
    what = f"training the {v.name} model ({v.model_key})"
    folder = None if demos is None else set_folder(demos)
    if folder is not None and folder.is_dir() and not (folder / "task.json").is_file():
        # (lfd-train refuses it too: a built-in task's time step and settings come from its task.json)
        where = folder if folder == demos else f"{demos}'s folder {folder.resolve()}"
        raise TrainingFailed(f"{what}: {where} has no task.json, which gives the model its task and time step; "
                             f"add one (lfd.learning.tasks.TaskSpec) to the demonstrations", 2)
    argv = ["--task", task, "--tool", v.tool, "--env", v.env, "--out", str(out), "--seed", str(train_seed)]
    if demos is not None:
        argv += ["--demos", str(demos)]
    if checkpoint_path(out).is_file():  # an interrupted training of this model: go on from its restarts
        argv.append("--resume")
    print(f"[evaluate] training {v.model_key}: lfd-train {shlex.join(argv)}", file=sys.stderr, flush=True)
    try:
        code = train_main(argv)
    except USER_ERRORS() as e:  # bad demonstrations, every restart failing, ...: its reason, one line
        raise TrainingFailed(f"{what} failed with exit status 2: {error_line(e)}", 2) from e
    if code:
        raise TrainingFailed(f"{what} stopped with exit status {code}", code)
    return out


def check_trained_on(task: str, models: Path, demos: Path | None, variants, demo_seeds) -> None:
    """``UsageError`` when a trained model among ``variants`` x ``demo_seeds`` was trained on other
    demonstrations than its draw's (``--demos``, or the default folder, for draw 0): it was
    evaluated as is, its tilt measured against demonstrations it never saw. Checked before any
    training, by the fingerprint of the recordings in its ``summary.json`` (a model trained before
    it was recorded, or whose demonstrations are not on this machine, is taken as it is)."""
    from lfd.learning.checkpoint import demos_fingerprint
    for k in demo_seeds:
        source = demos_for(task, demos, k) or default_demos(task)
        mine = None  # the draw's fingerprint, read once
        for v in variants:
            d = model_dir_for(models, v, k)
            if not is_trained(d):
                continue
            summary = _read_summary(d / "summary.json")
            recorded, steps = summary.get("demos_fingerprint"), summary.get("time_steps")
            if not isinstance(recorded, str) or not set_folder(source).is_dir():
                continue
            if mine is None:  # (loaded as it was trained: at least its number of steps)
                mine = demos_fingerprint(load_demos(source, time_steps=steps if isinstance(steps, int) and steps >= 2
                                                    else None), settings=False)
            if recorded != mine:
                raise UsageError(f"--models: {d} was trained on other demonstrations than {source}; give the "
                                 f"demonstrations it was trained on (--demos), another --models folder, or delete "
                                 f"that model to train it on these")


class _Progress:
    """One bar over every job, with the running success rate per variant."""

    def __init__(self, progress, total: int, done: dict):
        self.bar = progress(total=total, initial=len(done)) if progress else None
        self.tally: dict[str, list[int]] = {}
        for (name, _, _), r in done.items():
            self.add(name, r)

    def add(self, name: str, row: dict | None) -> None:
        t = self.tally.setdefault(name, [0, 0])
        t[0] += bool(row and row.get("success"))
        t[1] += 1
        if self.bar is not None:
            self.bar.set_postfix_str("  ".join(f"{n} {ok / max(k, 1):.0%}" for n, (ok, k) in self.tally.items()),
                                     refresh=False)

    def update(self, name: str, row: dict | None) -> None:
        self.add(name, row)
        if self.bar is not None:
            self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def evaluate(settings: EvalSettings, out_dir: Path, models: Path, demos: Path | None = None,
             progress=None, resume: bool = False) -> dict:
    """Run every variant on every scenario of every cell; write ``results.json``; return it.

    ``progress``: a tqdm-like class for the bar; ``resume``: continue the sweep logged in
    ``out_dir/runs.jsonl`` (without it, a folder that holds logged runs is refused: its runs
    would be mixed with this sweep's). Logged runs made with other settings (``run_settings_of``)
    are run again, not counted, and said so on stderr."""
    check_models_folder(models)
    by_name = {v.name: v for v in VARIANTS}
    variants = [by_name[n] for n in settings.variants]
    log = out_dir / "runs.jsonl"
    run_settings = run_settings_of(settings, models)
    done, crashed, lines, other, cut = read_log(log, settings.latency, run_settings)
    if lines and not resume:
        raise UsageError(f"{out_dir} already holds {lines} logged run(s): pass --resume to continue that "
                         "evaluation, or choose another --out")
    if other:
        print(f"[evaluate] {other} logged run(s) in {log} were made with other settings (latency mode, task, "
              f"roadmap size, models, bowl move, or with measured latency the executor and workers, which "
              f"set the CPU's load): they are not counted, and those of this sweep's scenes are run again with "
              f"{run_settings}", file=sys.stderr, flush=True)
    if settings.executor == "ray":
        require_ray(settings.address)  # before hours of training, not after
    check_trained_on(settings.task, models, demos, variants, settings.demo_seeds)  # before any training
    out_dir.mkdir(parents=True, exist_ok=True)
    summaries, tilt = {}, {}
    for k in settings.demo_seeds:
        for v in variants:
            summary = ensure_model(settings.task, models, demos, v, demo_seed=k) / "summary.json"
            summaries[v.name, k] = _read_summary(summary)
        tilt[k] = demo_tilt(demos_for(settings.task, demos, k) or default_demos(settings.task))["mean"]
    learn_s = {key: sm.get("learning_time_s", math.nan) for key, sm in summaries.items()}
    sets = {S: draw_scenarios(settings.task, settings.n_scenarios, S) for S in settings.seeds}
    if settings.move_bowl:
        with DumpReach(settings.task) as reach:
            sets = {S: [with_bowl_move(sc, reach) for sc in scs] for S, scs in sets.items()}
    wanted = {(v.name, k, sc.seed) for v in variants for k in settings.demo_seeds for scs in sets.values() for sc in scs}
    base_of = {sc.seed: S for S, scs in sets.items() for sc in scs}
    executor = make_executor(settings.executor, settings.workers, settings.address, initializer=init_worker)
    try:
        jobs = _jobs(settings, sets, variants, models, out_dir, executor, done)
        bar = _Progress(progress, len(wanted), {key: r for key, r in done.items() if key in wanted})
        with log.open("a") as fh:
            if cut:
                fh.write("\n")  # new runs start their own line

            def record(job: Job, r: dict | None, error: str | None) -> None:
                """Log one finished run (or its error) at once; its path and GIF go to their own files."""
                name, k, scenario = job.key
                if r is None:
                    r = {"variant": name, "scenario": scenario, "error": error, "attempts": 2,
                         "latency": settings.latency, "pace": EXEC_PACE}
                r.update(demo_seed=k, base_seed=base_of[scenario], settings=run_settings)
                if error is None:  # the tilt against the demonstrations' (sim.attitude); NaN without them
                    r.update(demo_tilt_deg=tilt[k],
                             tilt_error_deg=r.get("executed_tilt_deg", math.nan) - tilt[k],
                             planned_tilt_error_deg=r.get("planned_tilt_deg", math.nan) - tilt[k])
                path = r.pop("task_point_path", None)
                if path is not None:
                    r["task_point_path"] = save_path(out_dir, r, path)
                gif = r.pop("video_gif", None)
                if gif is not None:
                    _gif_path(out_dir, settings.task, name, scenario).write_bytes(gif)
                fh.write(json.dumps(r) + "\n")
                fh.flush()
                if error is None:
                    done[job.key] = r
                    crashed.pop(job.key, None)
                else:
                    crashed[job.key] = r
                    print(f"[evaluate] {name} scenario {scenario} failed twice: {error}", file=sys.stderr, flush=True)
                bar.update(name, None if error else r)

            run_jobs(run_one_shipped if executor.remote else run_one, jobs, record, executor)
        bar.close()
    finally:
        executor.close(cancel=True)  # (run_jobs closed it already unless something failed before)
    return _write_results(settings, out_dir, models, variants, sets, done, crashed, learn_s)


def _read_summary(path: Path) -> dict:
    """A model's ``summary.json`` (``{}`` when there is none); ``UsageError`` when it is damaged."""
    if not path.is_file():
        return {}
    rec = read_json(path, UsageError)
    if not isinstance(rec, dict):
        raise UsageError(f"{path}: a training summary is a JSON object, got {type(rec).__name__}")
    t = rec.get("learning_time_s", math.nan)  # (a string was found only when the table was printed)
    if isinstance(t, bool) or not isinstance(t, (int, float)):
        raise UsageError(f"{path}: learning_time_s must be a number of seconds, got {t!r}")
    return rec


def _gif_path(out_dir: Path, task: str, variant: str, scenario: int) -> Path:
    """Where a run's video goes (``--video``: the first scenario of each variant)."""
    return out_dir / f"{task}_{variant}_scenario{scenario}.gif"


def _jobs(settings: EvalSettings, sets: dict, variants: list, models: Path, out_dir: Path, executor,
          done: dict) -> list[Job]:
    """The jobs not done yet: one per (variant, demonstration draw, scenario); a remote executor
    gets each model's files once through ``executor.share``."""
    shared: dict = {}
    jobs = []
    for k in settings.demo_seeds:
        for v in variants:
            md = model_dir_for(models, v, k)
            for S, scenarios in sets.items():
                for i, sc in enumerate(scenarios):
                    if (v.name, k, sc.seed) in done:
                        continue
                    video = settings.video and i == 0 and S == settings.seeds[0] and k == settings.demo_seeds[0]
                    if executor.remote:
                        if md not in shared:
                            shared[md] = executor.share(model_files(md))
                        args: tuple = (shared[md], settings.task, sc, v, settings.roadmap_size, video, True,
                                       settings.latency)
                    else:
                        gif = str(_gif_path(out_dir, settings.task, v.name, sc.seed)) if video else None
                        args = (settings.task, sc, v, str(md), settings.roadmap_size, gif, True, settings.latency)
                    jobs.append(Job((v.name, k, sc.seed), args))
    return jobs


def _write_results(settings: EvalSettings, out_dir: Path, models: Path, variants: list, sets: dict, done: dict,
                   crashed: dict, learn_s: dict) -> dict:
    """``results.json`` from the logged runs of this sweep: every variant over all cells, each
    cell's own lines, the spread of the success rates over the cells, and the runs that crashed."""
    def line(name: str, keys) -> dict:
        keys = list(keys)
        times = [learn_s[name, k] for k in sorted({k for _, k, _ in keys})]  # one per demonstration draw
        return summarize([done[x] for x in keys if x in done], by_name[name],
                         times[0] if len(times) == 1 else float(np.mean(times)) if times else math.nan,
                         crashed=sum(x in crashed for x in keys))

    by_name = {v.name: v for v in variants}
    cells = []
    for S, scenarios in sets.items():
        for k in settings.demo_seeds:
            cells.append({"seed": S, "demo_seed": k, "variants": {
                v.name: line(v.name, [(v.name, k, sc.seed) for sc in scenarios]) for v in variants}})
    every = [sc for scs in sets.values() for sc in scs]
    results = {v.name: line(v.name, [(v.name, k, sc.seed) for k in settings.demo_seeds for sc in every])
               for v in variants}
    payload = {"task": settings.task, "seeds": list(settings.seeds), "demo_seeds": list(settings.demo_seeds),
               "n_scenarios": settings.n_scenarios, "roadmap_size": settings.roadmap_size,
               "latency": settings.latency, "executor": settings.executor, "move_bowl": settings.move_bowl,
               "models": {f"{v.name}@demos{k}": str(model_dir_for(models, v, k))
                          for k in settings.demo_seeds for v in variants},
               "variants": results, "cells": cells, "spread": spread(cells),
               "crashed": [{"variant": r["variant"], "demo_seed": r["demo_seed"], "scenario": r["scenario"],
                            "error": r["error"]} for r in crashed.values()
                           if r["variant"] in by_name and r["demo_seed"] in settings.demo_seeds
                           and r["scenario"] in {sc.seed for sc in every}],
               "scenario_set": [sc.to_dict() for sc in every]}
    tmp = out_dir / "results.json.tmp"
    tmp.write_text(json.dumps(strict_json(payload), indent=2, allow_nan=False) + "\n")
    tmp.replace(out_dir / "results.json")
    return payload
