"""Learning benchmarks.

``python benchmarks/learning.py [--runs N] [--restarts R]``: median learning time (``lfd.learning.learn.fit``
with default settings) for both tasks on ``runs/demos/<task>``; demonstrations are generated
with ``sim.demos.generate`` when absent. When the simulator cannot generate them, a synthetic
stand-in of the same size (11 demonstrations of ~15 s at the task's rate, Z=5, lfd.learning.synthetic)
is timed instead and marked ``"source": "synthetic"``. Writes ``runs/bench/learning.json``.

``python benchmarks/learning.py --compare``: accuracy of the ``full`` and ``block`` covariance
options (and of the volume prior) against known truth on several synthetic data sets
(plain, a start segment fixed to the robot, landmarks with full orientations), written to
``runs/bench/learning_compare.json``; the evidence for FitConfig's defaults.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lfd.cli import ArgumentParser, UsageError, run_main, writable_dir
from lfd.learning.learn import FitConfig, fit
from lfd.learning.synthetic import make_synthetic
from lfd.learning.tasks import task_from_name
from lfd.robot.kinematics import KinematicModel


def task_demos(task: str, kin):
    from lfd.learning.demos import demo_files, load_demos
    folder = ROOT / "runs" / "demos" / task
    if not demo_files(folder):
        try:
            from sim.demos import generate
            generate(task, folder, n=11, seed=0)
        except ImportError as e:
            print(f"{task}: sim.demos unavailable ({e}); timing a synthetic stand-in", flush=True)
            spec = task_from_name(task)
            per_step = round(15.0 / spec.dt / spec.time_steps)  # ~15 s demonstrations
            ds, _ = make_synthetic(kin, time_steps=spec.time_steps, seed=0, task=spec,
                                   samples_per_step=(int(per_step * 0.7), int(per_step * 1.3)))
            return ds, "synthetic"
    return load_demos(folder), str(folder.relative_to(ROOT))


def timing(args) -> dict:
    kin = KinematicModel.from_spec()
    out = {}
    for task in ("powder", "pour"):
        ds, source = task_demos(task, kin)
        kw = ds.task.fit_defaults() if ds.task else {}  # as train.py learns it
        if args.restarts:
            kw["restarts"] = args.restarts
        cfg = FitConfig(**kw)
        times, losses = [], []
        for r in range(args.runs):
            t = time.perf_counter()
            res = fit(ds, kin, cfg)
            times.append(time.perf_counter() - t)
            losses.append(res.final_loss)
            print(f"{task} run {r}: {times[-1]:.1f}s loss {res.final_loss:.3f} iters {res.em_iterations}", flush=True)
        out[task] = {"source": source, "n_demos": len(ds.demos), "n_observations": ds.n_observations,
                     "time_steps": cfg.time_steps, "restarts": cfg.restarts, "runs": args.runs,
                     "median_s": statistics.median(times), "times_s": times, "final_losses": losses}
    return out


def compare(args) -> dict:
    torch.set_num_threads(1)
    kin = KinematicModel.from_spec()
    kinds = {"plain": {}, "fixed_start": {"fixed_steps": 2}, "rotations": {"rotations": True}}
    rows = []
    for seed in range(args.seeds):
        for kind, kw in kinds.items():
            ds, truth = make_synthetic(kin, seed=seed, time_steps=8, **kw)
            variants = [("full", True), ("block", True)]
            if kind == "rotations":
                variants.append(("block", False))
            for cov, vol in variants:
                res = fit(ds, kin, FitConfig(time_steps=8, restarts=4, covariance=cov, volume_prior=vol))
                m = res.model
                row = {"seed": seed, "data": kind, "covariance": cov, "volume_prior": vol,
                       "tool_error_m": float(np.linalg.norm(m.tool.numpy() - truth.tool)),
                       "true_weight_before_pruning": res.env_before_pruning["bowl"],
                       "kept": list(res.kept_landmarks), "min_det_A": min(res.virtual_det),
                       "final_loss": res.final_loss, "time_s": res.timings["total_s"]}
                rows.append(row)
                print(json.dumps(row), flush=True)
    summary = {}
    for (cov, vol) in {(r["covariance"], r["volume_prior"]) for r in rows}:
        sel = [r for r in rows if r["covariance"] == cov and r["volume_prior"] == vol]
        summary[f"{cov}{'' if vol else '_no_volume_prior'}"] = {
            "median_tool_error_m": statistics.median(r["tool_error_m"] for r in sel),
            "max_tool_error_m": max(r["tool_error_m"] for r in sel),
            "min_true_weight": min(r["true_weight_before_pruning"] for r in sel),
            "only_true_landmark_kept": sum(r["kept"] == ["bowl"] for r in sel), "n": len(sel)}
    return {"rows": rows, "summary": summary}


def main(argv=None) -> int:
    p = ArgumentParser(prog="benchmarks/learning.py", description="lfd learning benchmarks")
    p.add_argument("--runs", type=int, default=3, help="timed fits per task (the median is reported)")
    p.add_argument("--restarts", type=int, default=None, help="restarts per fit (default: the task.json's, else FitConfig's)")
    p.add_argument("--compare", action="store_true", help="full vs block covariance on known truth")
    p.add_argument("--seeds", type=int, default=3, help="synthetic data sets per kind (--compare)")
    args = p.parse_args(argv)
    for name, value in (("--runs", args.runs), ("--restarts", args.restarts), ("--seeds", args.seeds)):
        if value is not None and value < 1:
            raise UsageError(f"{name} must be at least 1, got {value}")
    out_dir = writable_dir(ROOT / "runs" / "bench", what="output folder")
    if args.compare:
        result, path = compare(args), out_dir / "learning_compare.json"
    else:
        result, path = timing(args), out_dir / "learning.json"
    path.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    run_main(main, prog="benchmarks/learning.py")
