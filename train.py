"""Learn a task model from demonstrations: ``python train.py --task powder|pour [...]``.

Thin: parses arguments, loads (or generates) demonstrations, calls ``lfd.learn.fit``, writes
``model.pt``, ``config.json``, ``summary.json`` and TensorBoard logs into ``--out``.

Interruptions: after every restart the fit's progress is checkpointed into ``--out``
(``checkpoint.json`` + ``checkpoint_rNNN.pt``, see ``lfd.checkpoint``). Ctrl-C (SIGINT) or
SIGTERM stops the run with one line naming the checkpoint and the command that resumes it,
exit status 130 / 143; ``--resume`` carries on (same options and demonstrations, or it is
refused) and ends with the model an uninterrupted run would have learned. Every file is
written atomically, and never while a signal is being handled.
"""

from __future__ import annotations

import json
import shlex
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from lfd.cli import ArgumentParser, UsageError, run_main, writable_dir

ROOT = Path(__file__).resolve().parent


def parse_args(argv=None):
    p = ArgumentParser(prog="train.py", description=__doc__.splitlines()[0])
    p.add_argument("--task", required=True, choices=("powder", "pour"))
    p.add_argument("--demos", type=Path, help="demonstration folder (default runs/demos/<task>)")
    p.add_argument("--out", type=Path, help="output folder (default runs/<task>)")
    p.add_argument("--tool", default="learn", choices=("learn", "gripper", "tip"))
    p.add_argument("--env", default="learn", choices=("learn", "bowl"))
    p.add_argument("--restarts", type=int, default=None)
    p.add_argument("--time-steps", type=int, default=None)
    p.add_argument("--subsample", type=int, default=None, metavar="K",
                   help="learn from every K-th sample (the model's dt becomes K times the demonstrations'; "
                        "default: the task.json's subsample, 1 without one)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    p.add_argument("--covariance", default=None, choices=("full", "block"))
    p.add_argument("--init", default=None, choices=("reference", "random", "linear"),  # lfd.learn.INITS
                   help="restarts' first alignments: DTW onto a reference demonstration (default), "
                        "independent random warps (the paper's) or the uniform time warp")
    p.add_argument("--band", default=None, metavar="N|none",
                   help="keep every alignment within N steps of its restart's start (default 1); "
                        "'none' lets the DTW move freely, as in the paper")
    p.add_argument("--offsets", type=int, nargs="+", default=None,
                   help="permitted time-step transitions (default: lfd.learn.FitConfig's)")
    p.add_argument("--floor-task", type=float, default=None, metavar="M",
                   help="variance floor of the tool-point features, a standard deviation in metres "
                        "(lfd.priors; default: lfd.learn.FitConfig's)")
    p.add_argument("--floor-joint", type=float, default=None, metavar="RAD",
                   help="variance floor of the joint features, a standard deviation in radians "
                        "(default: lfd.learn.FitConfig's)")
    p.add_argument("--resume", action="store_true",
                   help="continue from the checkpoint in --out (same options and demonstrations)")
    args = p.parse_args(argv)
    if args.restarts is not None and args.restarts < 1:
        raise UsageError(f"--restarts must be at least 1, got {args.restarts}")
    if args.subsample is not None and args.subsample < 1:
        raise UsageError(f"--subsample must be at least 1, got {args.subsample}")
    if args.time_steps is not None and args.time_steps < 2:
        raise UsageError(f"--time-steps must be at least 2, got {args.time_steps}")
    return args


def ensure_demos(task: str, demos_dir: Path, seed: int) -> None:
    """Generate demonstrations with ``sim.demos.generate`` when ``demos_dir`` has none."""
    if demos_dir.is_dir() and any(demos_dir.glob("*.npz")):
        return
    try:
        from sim.demos import generate
    except ImportError as e:
        raise UsageError(f"--demos {demos_dir}: no demonstrations there, and they cannot be generated "
                         f"(sim.demos.generate is unavailable: {e})") from e
    print(f"no demonstrations in {demos_dir}; generating 11 with sim.demos ...", flush=True)
    generate(task, demos_dir, n=11, seed=seed)


class Logger:
    """Progress on stdout and TensorBoard scalars/images (the only SummaryWriter owner)."""

    def __init__(self, out: Path, joint_names):
        try:
            from torch.utils.tensorboard import SummaryWriter
            self.writer = SummaryWriter(str(out / "tensorboard"))
        except ImportError:
            self.writer = None
        self.joint_names = list(joint_names)
        self.step = 0
        self.t0 = time.perf_counter()

    def __call__(self, ev: dict) -> None:
        self.step += 1
        tag = f"{ev['stage']}{ev['restart']}"
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


def resume_command(argv) -> str:
    """The command line that resumes this run."""
    args = list(sys.argv[1:] if argv is None else argv)
    if "--resume" not in args:
        args.append("--resume")
    return shlex.join([sys.executable, sys.argv[0] or "train.py", *map(str, args)])


def main(argv=None) -> int:
    args = parse_args(argv)
    from lfd.checkpoint import Interrupted, InterruptGuard, checkpoint_path

    out = writable_dir(args.out or ROOT / "runs" / args.task)
    progress = {"done": None, "restarts": args.restarts}
    with InterruptGuard() as guard:
        try:
            return _train(args, out, guard, progress)
        except Interrupted as e:
            rec = checkpoint_path(out)
            if rec.is_file() and progress["done"] is not None:
                print(f"train.py: interrupted by {e.name}; checkpoint {rec} holds {progress['done']} of "
                      f"{progress['restarts']} restarts; resume with: {resume_command(argv)}",
                      file=sys.stderr, flush=True)
            else:
                print(f"train.py: interrupted by {e.name} before the first restart finished; no checkpoint "
                      f"in {out}, nothing to resume", file=sys.stderr, flush=True)
            return e.exit_status


def _train(args, out: Path, guard, progress: dict) -> int:
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
    demos_dir = args.demos or ROOT / "runs" / "demos" / args.task
    if args.demos is None:
        ensure_demos(args.task, demos_dir, args.seed)
    if args.device == "cuda" and not torch.cuda.is_available():
        raise UsageError("--device cuda: torch.cuda.is_available() is False on this machine")
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
    log = Logger(out, ds.joint_names)
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
    run_main(main, prog="train.py")
