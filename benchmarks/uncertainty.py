"""Calibration of the learner's standard errors, and the environment weights' two forms.

``python benchmarks/uncertainty.py [--seeds K] [--jackknife-em]``: on ``K`` independent synthetic
sets per kind (``lfd.learning.synthetic.make_synthetic``: the same hidden model, other draws of the
landmarks, trajectories and noise), the spread of the learned tool point across the sets (per axis
of the gripper frame) against the standard errors each estimate reports from one set:

* ``jackknife``: the fit's own (``FitResult.tool_se``, ``lfd.learning.uncertainty``): leave one
  demonstration out, the M-step refitted from the learned zeta at the remaining demonstrations'
  alignment, ``sqrt((M-1)/M sum (theta_m - theta_bar)^2)``;
* ``jackknife_em`` (with ``--jackknife-em``): the same with a whole EM per refit (one restart each,
  no grid search of the tool point);
* ``sandwich``: the cluster-robust covariance ``M/(M-1) H^-1 (sum_m (g_m - g_bar)(g_m - g_bar)^T) H^-1``
  of the profiled objective, ``g_m`` the gradient of demonstration m's share of it (taken through
  eta's closed form, which profiles eta out);
* ``naive``: ``2 H^-1`` of the profiled objective, every observation counted as independent.

A calibrated estimate has ``rms_se / spread`` near 1 and covers the truth within 2 SE in ~95% of
the sets. Writes ``runs/bench/uncertainty.json``.

``python benchmarks/uncertainty.py --weights [--seeds K]``: the fit with ``env_weights='simplex'``
and ``'affine'`` on the same sets (the true landmark's weight, the most negative weight, the tool
point's error, the loss), for the plain sets, a handover whose hand and body the data can hardly
tell apart (``handover``), and a task point
beyond two landmarks (weights 1.5 / -0.5, which only the affine form can express). Writes
``runs/bench/env_weights.json``.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lfd.cli import ArgumentParser, UsageError, run_main, writable_dir
from lfd.learning.em import EMFitter, FitData
from lfd.learning.learn import FitConfig, fit
from lfd.learning.model import aligned_nll_tensor
from lfd.learning.synthetic import as_handover, beyond_two_landmarks, make_synthetic
from lfd.robot.kinematics import KinematicModel

KINDS = {"plain": {}, "narrow": {"demo_spread": 0.03}, "moving": {"landmark_motion": 0.4, "Z": 3}}
DT = torch.float64
CPU = torch.device("cpu")


def _kept(ds, res):
    return [ds.landmark_names.index(n) for n in res.kept_landmarks]


def _profile(ds, kin, cfg, res):
    """``(theta0 (P,), zeta(theta) -> (tool, w), EMFitter, t_idx)`` at the learned model: the tool
    point, then the kept weights in their sum-to-one plane."""
    data = FitData(ds, kin, DT, CPU, cfg.features)
    kept = _kept(ds, res)
    fi = EMFitter(data, cfg, DT, CPU, kept)
    t_idx = torch.as_tensor(np.concatenate(res.alignments))
    tool, w = res.model.tool.to(DT), res.model.env.to(DT)
    B = fi.B if len(kept) > 1 else fi.B[:, :0]
    return torch.cat([tool, tool.new_zeros(B.shape[1])]), (lambda th: (th[:3], w + B @ th[3:])), fi, t_idx


def naive_se(ds, kin, cfg, res) -> np.ndarray:
    """``(3,)``: ``sqrt(diag(2 H^-1))`` of the tool point, H the profiled objective's Hessian,
    every observation counted as independent."""
    theta0, zeta, fi, t_idx = _profile(ds, kin, cfg, res)
    H = torch.autograd.functional.hessian(lambda th: fi.profiled(*zeta(th), t_idx, bound=False), theta0)
    return np.sqrt(np.abs(np.diagonal(2 * np.linalg.pinv(H.numpy()))[:3]))


def sandwich_se(ds, kin, cfg, res) -> np.ndarray:
    """``(3,)``: the cluster-robust sandwich of the tool point, one cluster per demonstration."""
    theta0, zeta, fi, t_idx = _profile(ds, kin, cfg, res)
    theta = theta0.clone().requires_grad_(True)
    tool, w = zeta(theta)
    f, A = fi.data.features(tool, w, fi.T_lm)
    mu, Sigma, _ = fi.closed_form(f, t_idx)
    L = torch.linalg.cholesky(Sigma)
    sigma_inv = torch.linalg.solve_triangular(L, torch.eye(fi.F, dtype=DT).expand_as(L), upper=False)
    obs = aligned_nll_tensor(f, t_idx, mu, sigma_inv, fi.s)  # (N,)
    shares = obs.new_zeros(fi.data.M).index_add(0, fi.data.demo, obs)
    shares = shares.index_add(0, fi.data.lm_demo, volume_prior_rows(A, fi))  # (M,)
    M = len(shares)
    G = torch.stack([torch.autograd.grad(shares[m], theta, retain_graph=True)[0] for m in range(M)])  # (M, P)
    H = torch.autograd.functional.hessian(lambda th: fi.profiled(*zeta(th), t_idx, bound=False), theta0)
    C = G - G.mean(0)
    Hinv = torch.linalg.pinv(H)
    V = Hinv @ (C.T @ C) @ Hinv * (M / (M - 1))
    return np.sqrt(np.abs(np.diagonal(V.detach().numpy())[:3]))


def volume_prior_rows(A, fi):
    """The volume prior per landmark row ``(R,)`` (``lfd.learning.priors.volume_prior`` before its sum)."""
    if not fi.cfg.volume_prior:
        return A.new_zeros(len(A))
    return -2.0 * fi.s * fi.data.vectors * fi.data.lm_counts * torch.linalg.slogdet(A)[1]


def jackknife_em_se(ds, kin, cfg, res) -> np.ndarray:
    """``(3,)``: the jackknife of the tool point with a whole EM per left-out demonstration, started
    from the learned zeta and the remaining demonstrations' alignments (no grid search)."""
    kept = _kept(ds, res)
    tool0, w0 = res.model.tool.to(DT), res.model.env.to(DT)
    data = FitData(ds, kin, DT, CPU, cfg.features)
    cfg_em = replace(cfg, solver=replace(cfg.solver, tool_search=0.0))
    M = data.M
    tools = []
    for m in range(M):
        others = [i for i in range(M) if i != m]
        state, _ = EMFitter(data.subset(others), cfg_em, DT, CPU, kept).em(
            tool0, w0, [res.alignments[i] for i in others], True, len(kept) > 1)
        tools.append(state[0].numpy())
    t = np.array(tools)
    return np.sqrt((M - 1) / M * ((t - t.mean(0)) ** 2).sum(0))


def _sets(kin, n: int, kw: dict):
    """``n`` synthetic sets ``(seed, (DemoSet, SyntheticTruth))`` from seeds 100, 101, ...; a draw whose
    IK fails (a target out of the arm's reach) is named and the next seed drawn instead."""
    seed, made = 100, 0
    while made < n:
        try:
            out = make_synthetic(kin, seed=seed, time_steps=8, **kw)
        except RuntimeError as e:
            print(f"seed {seed} {kw}: {e}; drawing the next", flush=True)
        else:
            yield seed, out
            made += 1
        seed += 1


def calibration(args) -> dict:
    torch.set_num_threads(1)
    kin = KinematicModel.from_spec()
    rows = []
    for kind, kw in KINDS.items():
        for seed, (ds, truth) in _sets(kin, args.seeds, kw):
            cfg = FitConfig(time_steps=8, restarts=args.restarts, seed=0)
            res = fit(ds, kin, cfg, workers=1)
            se, times = {"jackknife": res.tool_se}, {"jackknife": res.timings["uncertainty_s"]}
            for name, estimate in (("jackknife_em", jackknife_em_se), ("sandwich", sandwich_se), ("naive", naive_se)):
                if name == "jackknife_em" and not args.jackknife_em:
                    continue
                t = time.perf_counter()
                se[name] = estimate(ds, kin, cfg, res)
                times[name] = time.perf_counter() - t
            row = {"kind": kind, "seed": seed, "tool": res.model.tool.tolist(), "truth": truth.tool.tolist(),
                   "kept": list(res.kept_landmarks), "se": {k: np.asarray(v).tolist() for k, v in se.items()},
                   "time_s": times, "fit_s": res.timings["total_s"], "warnings": list(res.warnings)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    summary = {}
    for kind in KINDS:
        sel = [r for r in rows if r["kind"] == kind]
        tools, truth = np.array([r["tool"] for r in sel]), np.array(sel[0]["truth"])
        spread = tools.std(axis=0, ddof=1)
        rmse = np.sqrt(((tools - truth) ** 2).mean(axis=0))
        summary[kind] = {"n_sets": len(sel), "spread_m": spread.tolist(), "rms_error_m": rmse.tolist()}
        for name in sel[0]["se"]:
            s = np.array([r["se"][name] for r in sel])  # (K, 3)
            z = (tools - truth) / s
            summary[kind][name] = {"rms_se_m": np.sqrt((s ** 2).mean(0)).tolist(),
                                   "rms_se_over_spread": (np.sqrt((s ** 2).mean(0)) / spread).tolist(),
                                   "rms_se_over_rms_error": (np.sqrt((s ** 2).mean(0)) / rmse).tolist(),
                                   "covered_within_2se": float((np.abs(z) <= 2).mean()),
                                   "median_time_s": float(np.median([r["time_s"][name] for r in sel]))}
    return {"rows": rows, "summary": summary}


def weights(args) -> dict:
    torch.set_num_threads(1)
    kin = KinematicModel.from_spec()
    rows = []
    for (seed, (plain, truth)), (_, (moving, truth_m)) in zip(_sets(kin, args.seeds, {}),
                                                           _sets(kin, args.seeds, {"landmark_motion": 0.4, "Z": 3})):
        sets = {"plain": (plain, truth, "bowl"),
                "handover": (as_handover(moving, np.random.default_rng(seed)), truth_m, "hand"),
                "beyond": (beyond_two_landmarks(plain, np.random.default_rng(seed)), truth, "a")}
        for kind, (ds, tr, true_name) in sets.items():
            for form in ("simplex", "affine"):
                res = fit(ds, kin, FitConfig(time_steps=8, restarts=args.restarts, seed=0, env_weights=form),
                          workers=1)
                row = {"kind": kind, "seed": seed, "env_weights": form,
                       "true_weight": res.env_before_pruning[true_name],
                       "min_weight": min(res.env_before_pruning.values()),
                       "weights": res.env_before_pruning, "kept": dict(zip(res.kept_landmarks,
                                                                            res.model.env.tolist())),
                       "tool_error_m": float(np.linalg.norm(res.model.tool.numpy() - tr.tool)),
                       "final_loss": res.final_loss, "time_s": res.timings["total_s"],
                       "about_equal": list(res.uncertainty.about_equal),
                       "evidence": res.uncertainty.evidence, "warnings": list(res.warnings)}
                rows.append(row)
                print(json.dumps(row), flush=True)
    summary = {}
    for kind in ("plain", "handover", "beyond"):
        for form in ("simplex", "affine"):
            sel = [r for r in rows if r["kind"] == kind and r["env_weights"] == form]
            summary[f"{kind}/{form}"] = {
                "median_tool_error_m": float(np.median([r["tool_error_m"] for r in sel])),
                "max_tool_error_m": float(np.max([r["tool_error_m"] for r in sel])),
                "median_true_weight": float(np.median([r["true_weight"] for r in sel])),
                "min_weight": float(np.min([r["min_weight"] for r in sel])),
                "median_final_loss": float(np.median([r["final_loss"] for r in sel])),
                "warned_about_equal": sum(len(r["about_equal"]) > 1 for r in sel), "n": len(sel)}
    return {"rows": rows, "summary": summary}


def main(argv=None) -> int:
    p = ArgumentParser(prog="benchmarks/uncertainty.py", description="calibration of the learner's standard errors")
    p.add_argument("--seeds", type=int, default=12, help="independent synthetic sets per kind")
    p.add_argument("--restarts", type=int, default=2, help="restarts per fit")
    p.add_argument("--jackknife-em", action="store_true", help="also the jackknife with a whole EM per refit")
    p.add_argument("--weights", action="store_true", help="simplex vs affine environment weights")
    args = p.parse_args(argv)
    for name, value in (("--seeds", args.seeds), ("--restarts", args.restarts)):
        if value < 2 - (name == "--restarts"):
            raise UsageError(f"{name} must be at least {2 - (name == '--restarts')}, got {value}")
    out_dir = writable_dir(ROOT / "runs" / "bench", what="output folder")
    if args.weights:
        result, path = weights(args), out_dir / "env_weights.json"
    else:
        result, path = calibration(args), out_dir / "uncertainty.json"
    path.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    run_main(main, prog="benchmarks/uncertainty.py")
