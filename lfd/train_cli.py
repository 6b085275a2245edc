"""Learn a task model from demonstrations: ``lfd-train --task powder|pour [...]`` (or ``python train.py``).

Loads (or, with the simulator installed, generates) demonstrations, calls ``lfd.learn.fit``, and
writes ``model.pt``, ``config.json``, ``summary.json`` and TensorBoard logs into ``--out``.
Relative paths and the defaults (``./runs/<task>``, ``./runs/demos/<task>``) are taken from the
current working directory.

Interruptions: after every restart the fit's progress is checkpointed into ``--out``
(``checkpoint.json`` + ``checkpoint_rNNN.pt``, see ``lfd.checkpoint``). Ctrl-C (SIGINT) or
SIGTERM stops the run with one line naming the checkpoint and the command that resumes it,
exit status 130 / 143; ``--resume`` carries on (same options and demonstrations, or it is
refused) and ends with the model an uninterrupted run would have learned. Every file is
written atomically, and never while a signal is being handled.

Failures: a run that fails (bad input, every restart failing, a bug), or is interrupted before
its first checkpoint, removes the ``--out`` folder it created; a folder that existed before the
run is left in place. The exception is never swallowed (``run_main`` turns user errors into one
line and exit status 2).

This module imports no simulator: demonstrations are generated (``sim.demos.generate``) only
when the default demonstration folder is empty, and only if the ``sim`` package is installed.
"""

from __future__ import annotations

import functools
import json
import os
import shlex
import shutil
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from lfd.cli import ArgumentParser, UsageError, run_main, writable_dir

__all__ = ["PROG", "TOOL_CHOICES", "ENV_CHOICES", "build_parser", "parse_args", "check_device", "main", "cli",
           "default_out", "default_demos", "Logger"]

PROG = "lfd-train"

# The paper's names of the landmark choices (its tables' rows; ``plan.py --variants`` combines them
# as tool+env), mapped to ``lfd.learn.FitConfig``'s values, which are accepted as aliases.
TOOL_CHOICES = {"learned": "learn", "manual": "tip", "arbitrary": "gripper",
                "learn": "learn", "tip": "tip", "gripper": "gripper"}
ENV_CHOICES = {"learned": "learn", "manual": "bowl", "learn": "learn", "bowl": "bowl"}


def default_out(task: str) -> Path:
    """``--out``'s default: ``./runs/<task>`` in the current working directory."""
    return Path("runs") / task


def default_demos(task: str) -> Path:
    """``--demos``' default: ``./runs/demos/<task>`` in the current working directory."""
    return Path("runs") / "demos" / task


def check_device(text: str) -> str:
    """``text`` if it names a torch device (``cpu``, ``cuda``, ``cuda:1``, ``mps``, ...);
    ``UsageError`` saying why otherwise. Whether this machine has it is checked before the fit."""
    import torch
    try:
        torch.device(text)
    except (RuntimeError, ValueError, TypeError) as e:
        why = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise UsageError(f"--device {text!r} is not a torch device string, e.g. cpu, cuda, cuda:1, mps "
                         f"(torch.device: {why})") from None
    return text


def _check_device_available(text: str) -> None:
    """``UsageError`` when this machine cannot put a tensor on the device ``text``."""
    import torch
    dev = torch.device(text)
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise UsageError(f"--device {text}: torch.cuda.is_available() is False on this machine")
    try:
        torch.zeros(1, device=dev) + 1
    except (RuntimeError, AssertionError, ValueError) as e:
        why = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise UsageError(f"--device {text}: this machine's torch cannot use it ({why})") from None


def build_parser(prog: str = PROG) -> ArgumentParser:
    """The parser of ``lfd-train`` / ``train.py`` (``prog``)."""
    p = ArgumentParser(prog=prog, description="Learn a task model from demonstrations (lfd-train; python "
                                              "train.py in a source checkout). Relative paths and the "
                                              "defaults are taken from the current working directory.")
    p.add_argument("--task", required=True, choices=("powder", "pour"), help="the task to learn (required)")
    p.add_argument("--demos", type=Path, metavar="DIR",
                   help="demonstration folder (default: ./runs/demos/<task>, generated with the simulator "
                        "when empty)")
    p.add_argument("--out", type=Path, metavar="DIR", help="output folder (default: ./runs/<task>)")
    p.add_argument("--tool", default="learned", choices=tuple(TOOL_CHOICES), metavar="{learned,manual,arbitrary}",
                   help="tool landmark: learned from the demonstrations, manual (the task's hand-picked tool "
                        "point, e.g. the spoon's tip) or arbitrary (the gripper's origin); learn, tip, gripper "
                        "are accepted as the same")
    p.add_argument("--env", default="learned", choices=tuple(ENV_CHOICES), metavar="{learned,manual}",
                   help="environment landmark: learned weights over the sensed landmarks, or manual (the "
                        "task's reference landmark, the bowl); learn, bowl are accepted as the same")
    p.add_argument("--restarts", type=int, default=None, metavar="N",
                   help="EM restarts from different starts (default: lfd.learn.FitConfig's, 4)")
    p.add_argument("--time-steps", type=int, default=None, metavar="T",
                   help="time steps of the model (default: the task.json's, 24 without one)")
    p.add_argument("--subsample", type=int, default=None, metavar="K",
                   help="learn from every K-th sample (the model's dt becomes K times the demonstrations'; "
                        "default: the task.json's subsample, 1 without one)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the restarts (and of the demonstrations, when they are generated)")
    p.add_argument("--device", default="cpu", type=str, metavar="DEVICE",
                   help="torch device string to learn on: cpu, cuda, cuda:1, mps, ...")
    p.add_argument("--covariance", default=None, choices=("full", "block"),
                   help="per-step covariance: block (joints independent of the task features) or full, "
                        "the paper's (default: block)")
    p.add_argument("--init", default=None, choices=("reference", "random", "linear"),  # lfd.learn.INITS
                   help="restarts' first alignments: DTW onto a reference demonstration (default: reference), "
                        "independent random warps (the paper's) or the uniform time warp")
    p.add_argument("--band", default=None, metavar="N|none",
                   help="keep every alignment within N steps of its restart's start (default: 1); "
                        "'none' lets the DTW move freely, as in the paper")
    p.add_argument("--offsets", type=int, nargs="+", default=None, metavar="K",
                   help="permitted time-step transitions (default: lfd.learn.FitConfig's, 0 1 2)")
    p.add_argument("--floor-task", type=float, default=None, metavar="M",
                   help="variance floor of the tool-point features, a standard deviation in metres "
                        "(lfd.priors; default: lfd.learn.FitConfig's, 0.001)")
    p.add_argument("--floor-joint", type=float, default=None, metavar="RAD",
                   help="variance floor of the joint features, a standard deviation in radians "
                        "(default: lfd.learn.FitConfig's, 0.001)")
    p.add_argument("--resume", action="store_true",
                   help="continue from the checkpoint in --out (same options and demonstrations)")
    p.add_argument("--quiet", action="store_true",
                   help="no per-iteration progress lines (the summary lines and warnings stay)")
    return p


def parse_args(argv=None, prog: str = PROG):
    """The options of ``argv`` (default ``sys.argv[1:]``), checked; ``--tool``/``--env`` become
    ``FitConfig``'s values. ``UsageError`` (or argparse's exit 2) on bad input."""
    args = build_parser(prog).parse_args(argv)
    if args.restarts is not None and args.restarts < 1:
        raise UsageError(f"--restarts must be at least 1, got {args.restarts}")
    if args.subsample is not None and args.subsample < 1:
        raise UsageError(f"--subsample must be at least 1, got {args.subsample}")
    if args.time_steps is not None and args.time_steps < 2:
        raise UsageError(f"--time-steps must be at least 2, got {args.time_steps}")
    check_device(args.device)
    args.tool, args.env = TOOL_CHOICES[args.tool], ENV_CHOICES[args.env]
    return args


def ensure_demos(task: str, demos_dir: Path, seed: int) -> None:
    """Generate demonstrations with ``sim.demos.generate`` when ``demos_dir`` has none (the
    simulator is imported only here, and only when it is installed)."""
    if demos_dir.is_dir() and any(demos_dir.glob("*.npz")):
        return
    try:
        import importlib
        generate = importlib.import_module("sim.demos").generate
    except ImportError as e:
        raise UsageError(f"--demos {demos_dir}: no demonstrations there, and they cannot be generated "
                         f"(the simulator, sim.demos, is unavailable: {e}); pass --demos DIR") from e
    print(f"no demonstrations in {demos_dir}; generating 11 with sim.demos ...", flush=True)
    generate(task, demos_dir, n=11, seed=seed)


class Logger:
    """Progress on stdout and TensorBoard scalars/images (the only SummaryWriter owner).

    ``quiet``: no line per EM iteration. Without TensorBoard installed it says so once on stderr
    and writes no logs."""

    def __init__(self, out: Path, joint_names, quiet: bool = False, prog: str = PROG):
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError as e:
            self.writer = None
            print(f"{prog}: warning: TensorBoard is not installed ({e}), so no TensorBoard logs are written "
                  f"to {out / 'tensorboard'}; pip install tensorboard to have them", file=sys.stderr, flush=True)
        else:
            self.writer = SummaryWriter(str(out / "tensorboard"))
        self.joint_names = list(joint_names)
        self.quiet = quiet
        self.step = 0
        self.t0 = time.perf_counter()

    def __call__(self, ev: dict) -> None:
        self.step += 1
        tag = f"{ev['stage']}{ev['restart']}"
        if not self.quiet:
            print(f"[{time.perf_counter() - self.t0:6.1f}s] {ev['stage']} {ev['restart']} iter {ev['iteration'] + 1}: "
                  f"loss {ev['loss']:.4f}  tool {np.round(ev['tool'], 3).tolist()}", flush=True)
        w = self.writer
        if w is None:
            return
        w.add_scalar(f"loss/{tag}", ev["loss"], ev["iteration"])
        w.add_scalar("loss/all", ev["loss"], self.step)
        for name, x in zip(ev["landmarks"], ev["env"]):
            w.add_scalar(f"landmarks/{name}", float(x), self.step)
        for axis, x in zip("xyz", ev["tool"]):
            w.add_scalar(f"tool/{axis}", float(x), self.step)

    def final(self, result) -> None:
        w = self.writer
        if w is None:
            return
        m = result.model
        std = np.sqrt(np.diagonal(m.covariances.cpu().numpy(), axis1=1, axis2=2))  # (T, F)
        names = self.joint_names + ["task_x", "task_y", "task_z"]
        for t in range(m.time_steps):
            for j, n in enumerate(names):
                w.add_scalar(f"features/std/{n}", float(std[t, j]), t)
            w.add_scalar("alignment/effective_demos", result.effective_demos[t], t)
        for i, a in enumerate(result.alignments):
            img = np.zeros((1, m.time_steps, len(a)), dtype=np.float32)  # (C, H = step, W = sample)
            img[0, a, np.arange(len(a))] = 1.0
            w.add_image(f"alignment/demo_{i:02d}", img, 0)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None


def resume_command(argv, prog: str = PROG) -> str:
    """The command line that resumes this run (``python train.py ...`` when run as that script)."""
    args = list(sys.argv[1:] if argv is None else argv)
    if "--resume" not in args:
        args.append("--resume")
    head = [sys.executable, sys.argv[0]] if prog.endswith(".py") and sys.argv[0].endswith(".py") else [PROG]
    return shlex.join([*head, *map(str, args)])


def _first_missing(path: Path) -> Path | None:
    """The outermost folder on the way to ``path`` that does not exist yet (what creating
    ``path`` makes), or None when ``path`` exists."""
    path = Path(os.path.abspath(path))
    missing = None
    for p in (path, *path.parents):
        if p.exists() or p.is_symlink():
            break
        missing = p
    return missing


def main(argv=None, prog: str = PROG) -> int:
    """``lfd-train`` / ``python train.py``: 0 on success, 130 / 143 when interrupted; raises
    ``UsageError`` (and the other ``lfd.cli.USER_ERRORS``) on bad input."""
    args = parse_args(argv, prog=prog)
    from lfd.checkpoint import Interrupted, InterruptGuard, checkpoint_path

    out_arg = args.out or default_out(args.task)
    created = _first_missing(out_arg)
    out = writable_dir(out_arg)
    progress = {"done": None, "restarts": args.restarts}
    keep = False
    try:
        with InterruptGuard() as guard:
            try:
                code = _train(args, out, guard, progress, prog)
                keep = code == 0
                return code
            except Interrupted as e:
                rec = checkpoint_path(out)
                if rec.is_file() and progress["done"] is not None:
                    keep = True  # the checkpoint is what --resume continues
                    print(f"{prog}: interrupted by {e.name}; checkpoint {rec} holds {progress['done']} of "
                          f"{progress['restarts']} restarts; resume with: {resume_command(argv, prog)}",
                          file=sys.stderr, flush=True)
                else:
                    print(f"{prog}: interrupted by {e.name} before the first restart finished; no checkpoint "
                          f"in {out}, nothing to resume", file=sys.stderr, flush=True)
                return e.exit_status
    finally:
        if not keep and created is not None:  # no empty or half-written folder of ours is left
            shutil.rmtree(created, ignore_errors=True)


def cli() -> None:
    """The ``lfd-train`` console script."""
    run_main(main, prog=PROG)


def _train(args, out: Path, guard, progress: dict, prog: str = PROG) -> int:
    import torch

    from lfd.checkpoint import (CheckpointError, atomic_write_text, checkpoint_path,
                                config_record, demos_fingerprint, load_checkpoint, remove_checkpoint,
                                save_checkpoint)
    from lfd.demos import load_demos
    from lfd.kinematics import KinematicModel
    from lfd.learn import FitConfig, fit

    resumed = None
    if args.resume:
        try:
            resumed = load_checkpoint(out)
        except CheckpointError as e:
            raise UsageError(f"--resume: {e}") from e
        progress["done"] = resumed.restarts_done
    demos_dir = args.demos or default_demos(args.task)
    if args.demos is None:
        ensure_demos(args.task, demos_dir, args.seed)
    _check_device_available(args.device)
    ds = load_demos(demos_dir, time_steps=args.time_steps)
    if ds.task is not None and ds.task.name != args.task:
        raise UsageError(f"--demos {demos_dir}: demonstrations of task {ds.task.name!r}, not {args.task!r}")
    kw = {"tool": args.tool, "env": args.env, "seed": args.seed, "device": args.device}
    for key, val in (("restarts", args.restarts), ("covariance", args.covariance), ("init", args.init),
                     ("offsets", tuple(args.offsets) if args.offsets else None),
                     ("floor_task", args.floor_task), ("floor_joint", args.floor_joint)):
        if val is not None:
            kw[key] = val
    if args.band is not None:
        try:
            kw["band"] = None if args.band.lower() == "none" else int(args.band)
        except ValueError:
            raise UsageError(f"--band must be a whole number of steps or 'none', got {args.band!r}") from None
    kw["time_steps"] = args.time_steps or (ds.task.time_steps if ds.task else 24)
    kw["subsample"] = args.subsample or (ds.task.subsample if ds.task else 1)
    if kw["subsample"] > 1 and ds.task is None:
        raise UsageError(f"--subsample {kw['subsample']}: {demos_dir} has no task.json, where the model's "
                         f"sampling interval is kept; add one (lfd.tasks.TaskSpec) or leave --subsample out")
    try:
        cfg = FitConfig(**kw)
    except ValueError as e:
        raise UsageError(str(e)) from e
    progress["restarts"] = cfg.restarts
    if resumed is not None:
        why = resumed.mismatch(config_record(cfg), demos_fingerprint(ds))
        if why:
            raise UsageError(f"--resume: {checkpoint_path(out)} was {why}; resume with the options and "
                             f"demonstrations it was made with, or drop --resume to start over")
        print(f"resuming from {checkpoint_path(out)}: {resumed.restarts_done} of {cfg.restarts} restarts done",
              flush=True)
    elif checkpoint_path(out).is_file():  # an older run's; this run's first restart writes a new one
        print(f"starting over: removing the checkpoint of an earlier run in {out} (--resume continues one)",
              flush=True)
        with guard.critical():
            remove_checkpoint(out)
    kin = KinematicModel.from_spec(ds.robot)
    n_obs = ds.subsample(cfg.subsample).n_observations  # what the fit learns from
    every = f" (1 in {cfg.subsample} of {ds.n_observations})" if cfg.subsample > 1 else ""
    print(f"{len(ds.demos)} demonstrations, {n_obs} observations{every} at dt {ds.dt * cfg.subsample:g} s, landmarks "
          f"{list(ds.landmark_names)}; T={cfg.time_steps}, {cfg.restarts} restarts", flush=True)
    log = Logger(out, ds.joint_names, quiet=args.quiet, prog=prog)
    shown = [len(resumed.notes) if resumed else 0]

    def on_restart(p) -> None:
        with guard.critical():
            save_checkpoint(out, p)
            progress["done"] = p.restarts_done
        for note in p.notes[shown[0]:]:  # progress on stdout; stderr keeps one line for errors
            print(f"warning: {note}", flush=True)
        shown[0] = len(p.notes)

    try:
        with warnings.catch_warnings():  # the fit's RuntimeWarnings are shown by on_restart / at the end
            warnings.filterwarnings("ignore", category=RuntimeWarning, module=r"lfd\.learn")
            result = fit(ds, kin, cfg, callback=log, on_restart=on_restart, resume=resumed)
        log.final(result)
    except ValueError as e:  # every restart failed, the refit failed, a non-finite model
        raise UsageError(str(e)) from e
    finally:
        log.close()
    m = result.model
    summary = {"learning_time_s": result.timings["total_s"], "n_demos": len(ds.demos),
               "n_observations": n_obs, "subsample": cfg.subsample, "dt": float(m.task.dt) if m.task else None,
               "time_steps": cfg.time_steps, "restarts": cfg.restarts,
               "covariance": cfg.covariance, "seed": cfg.seed, "final_loss": result.final_loss,
               "restart_losses": [x if np.isfinite(x) else None for x in result.restart_losses],
               "em_iterations": list(result.em_iterations), "best_restart": result.best_restart,
               "resumed_restarts": result.resumed_restarts,
               "tool_point": m.tool.cpu().tolist(),
               "env_weights": {n: float(x) for n, x in zip(m.landmark_names, m.env.cpu().tolist())},
               "env_weights_before_pruning": result.env_before_pruning,
               "kept_landmarks": list(result.kept_landmarks), "virtual_det": list(result.virtual_det),
               "effective_demos_per_step": [round(x, 2) for x in result.effective_demos],
               "warnings": list(result.warnings), "timings": result.timings}
    gt = ds.ground_truth  # evaluation only: never passed to the fit
    if gt:
        if "tool_point" in gt:
            summary["tool_point_error_m"] = float(np.linalg.norm(np.asarray(gt["tool_point"]) - m.tool.cpu().numpy()))
        if "bowl_landmark" in gt:
            summary["bowl_weight"] = result.env_before_pruning.get(gt["bowl_landmark"])
    with guard.critical():  # the model's files, each atomic, and never split by a signal
        m.save(out)
        atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    print(f"learned in {summary['learning_time_s']:.1f}s: tool {np.round(m.tool.cpu().numpy(), 4).tolist()}, "
          f"env {summary['env_weights']}; wrote {out}", flush=True)
    for w in result.warnings[shown[0]:]:
        print(f"warning: {w}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    run_main(functools.partial(main, prog=PROG), prog=PROG)
