"""What the demonstrations leave uncertain in a learned zeta (``FitResult.uncertainty``).

The demonstrations are the independent units: the samples of one demonstration share its scene,
its landmarks' places and its trajectory, so their errors are strongly correlated, and a
curvature that counts the ``N`` samples as independent observations is over-confident. Every
figure here resamples or compares over demonstrations.

* **Standard errors of zeta** (``jackknife``): the tool point (gripper frame, m, per axis) and the
  kept landmarks' weights by the leave-one-demonstration-out jackknife, ``V = (M - 1) / M sum_m
  (theta_m - theta_bar)(theta_m - theta_bar)^T``, each ``theta_m`` the M-step (LBFGS on the profiled
  objective, ``EMFitter.fit_zeta``) on the other demonstrations at their learned alignment,
  started from the learned zeta, without the tool-radius bound (it holds the tool point, it does
  not inform it). Measured against the spread of the tool point learned from independent
  synthetic sets (``benchmarks/uncertainty.py``, 12 sets of 11 demonstrations for each of three
  kinds): this standard error is 0.73-1.29 of the spread per axis, where the cluster-robust
  sandwich of the profiled objective's Hessian gave 0.51-0.89 and the Hessian counting every
  sample as independent 0.36-0.71 (over-confident), and a jackknife with a whole EM per refit
  0.76-1.38 at up to 3 times the cost (docs/DESIGN.md, *Environment weights and what the
  demonstrations leave uncertain*).
* **Directions the data do not hold** (``flat_coordinates``): where the profiled objective is flat
  (the tool point along an axis the gripper never turned about in the virtual landmark's frame,
  weights of landmarks rigidly attached to each other), every refit stays where it starts and a
  jackknife would say 0. There the Hessian of the profiled objective (without the bound) has an
  eigenvalue under ``FLAT`` of its largest, or a negative one; a coordinate reaching into such a
  direction has an infinite standard error.
* **Landmarks that explain the data about equally** (``landmark_evidence``): for every sensed
  landmark z, the model with all the weight on z (its tool point refitted by LBFGS from the
  learned one at the learned alignment) against the learned model, one held-out demonstration at
  a time: each model's per-step Gaussians (eta, closed form) fitted to the other demonstrations,
  and Eq. 3 summed over the held-out one's observations at its alignment (``heldout_losses``).
  z explains the demonstrations about as well as the learned model unless it is worse on so
  many of them that a coin would be that one-sided less than ``ALPHA`` of the time (a one-sided
  sign test over the independent units; ``worse_needed``: 5 of 5, 7 of 8, 9 of 11; differences
  under ``TIED`` per observation are ties and not counted). Two or more such landmarks: the data
  cannot tell them apart (a hand and the body that carries it). Held out, because in-sample the
  learned model's eta (hundreds of numbers) has seen every demonstration: measured on
  handover-like sets (``tests/test_uncertainty.py``), a torso that moved with the hand was worse
  in-sample on 7 of 8 demonstrations and held out on 6, and across four draws of such sets the
  learner chose the hand, the torso and a mixture. A mixture the data need (a point midway
  between two landmarks) leaves each landmark alone worse on every demonstration, and is not
  reported.

``uncertainty_notes`` words the warnings: landmarks about equal, and a tool point beyond the
tool's size (``FitConfig.tool_size``), saying whether its standard error places it there.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import torch

__all__ = ["ALPHA", "FLAT", "Z_CRIT", "Uncertainty", "estimate_uncertainty", "flat_coordinates", "heldout_losses",
           "jackknife", "landmark_evidence", "uncertainty_notes", "worse_needed"]

ALPHA = 0.05  # a landmark alone is told from the learned model when a coin would be as one-sided less often
Z_CRIT = 2.0  # standard errors: a tool point beyond the tool's size by less than this many is not placed there
FLAT = 1e-9  # an eigenvalue of the profiled objective's Hessian under this share of its largest: flat
TIED = 1e-6  # Eq. 3 units per observation: a held-out difference this small is a tie


@dataclass(frozen=True)
class Uncertainty:
    """What the demonstrations leave uncertain (module docstring).

    tool_cov : ``(3, 3)`` m^2, the tool point's covariance in the gripper frame, ``inf`` on the
        diagonal along an axis the demonstrations do not determine; None when it is not learned.
    env_se : the kept landmarks' weights' standard errors by name (``inf``: not determined);
        empty when the weights are not learned or one landmark is kept.
    evidence : per sensed landmark ``(worse, counted, gap)``: on how many held-out demonstrations the
        model with all the weight on it is worse than the learned model, of how many not tied,
        and by how much on average (Eq. 3 units per demonstration); empty when the weights are
        not learned.
    about_equal : the landmarks not told from the learned model (``worse < worse_needed(counted)``),
        best first (by ``gap``).
    failures : what failed (a refit that diverged, as a restart can: ``lfd.learning.em.EM_FAILURES``),
        one line each; the standard errors then rest on the other refits, and a landmark whose
        model failed has no evidence.
    time_s : seconds it took.
    """

    tool_cov: np.ndarray | None
    env_se: dict = field(default_factory=dict)
    evidence: dict = field(default_factory=dict)
    about_equal: tuple[str, ...] = ()
    failures: tuple[str, ...] = ()
    time_s: float = 0.0

    @property
    def tool_se(self) -> np.ndarray | None:
        """``(3,)`` m per axis of the gripper frame (``inf``: not determined), or None."""
        return None if self.tool_cov is None else np.sqrt(np.diagonal(self.tool_cov))

    def radial_se(self, tool: np.ndarray) -> float:
        """The standard error (m) of the tool point's distance from the gripper's origin at ``tool
        (3,)``: ``inf`` when that direction reaches an undetermined axis; 0 when not learned."""
        if self.tool_cov is None:
            return 0.0
        r = np.asarray(tool, dtype=float)
        r = r / np.linalg.norm(r) if np.linalg.norm(r) > 0 else np.full(3, 3 ** -0.5)
        C = self.tool_cov
        if (np.abs(r[~np.isfinite(np.diagonal(C))]) > 1e-3).any():
            return math.inf
        return float(np.sqrt(max(r @ np.where(np.isfinite(C), C, 0.0) @ r, 0.0)))


def _coordinates(fitter, tool, w, learn_tool: bool, learn_env: bool):
    """``(theta0 (P,), zeta(theta) -> (tool, w), J (3 + Z or 3 or Z, P))``: the learned zeta's free
    coordinates (the tool point, then the weights in their sum-to-one plane ``w + B u``) and the
    map of a change in them onto the tool point and the weights that are learned."""
    n_tool = 3 if learn_tool else 0
    B = fitter.B if learn_env and fitter.Z > 1 else fitter.B[:, :0]  # (Z, Z-1) or none
    theta0 = torch.cat([tool[:n_tool], tool.new_zeros(B.shape[1])])

    def zeta(theta):
        return (theta[:3] if learn_tool else tool), w + B @ theta[n_tool:]

    eye = torch.eye(n_tool, dtype=B.dtype, device=B.device)
    return theta0, zeta, (torch.block_diag(eye, B) if B.shape[1] else eye)


def flat_coordinates(fitter, tool, w, t_idx, learn_tool: bool, learn_env: bool) -> np.ndarray:
    """``(P',) bool`` over the tool point's axes (when ``learn_tool``) then the weights (when
    ``learn_env`` and ``Z > 1``): True where the coordinate reaches into a direction along which
    the profiled objective at the alignment ``t_idx (N,)`` is flat or falls (module docstring)."""
    theta0, zeta, J = _coordinates(fitter, tool, w, learn_tool, learn_env)
    if theta0.numel() == 0:
        return np.zeros(J.shape[0], dtype=bool)
    H = torch.autograd.functional.hessian(lambda th: fitter.profiled(*zeta(th), t_idx, bound=False), theta0)
    lam, Q = torch.linalg.eigh(0.5 * (H + H.T))
    flat = lam <= FLAT * lam.abs().max()
    reach = ((J @ Q[:, flat]) ** 2).sum(1)  # (P',) each coordinate's share of the flat directions
    return (reach > 1e-6).cpu().numpy()


def jackknife(data, cfg, dtype, device, tool, w, align, kept, workers: int = 1) -> tuple[np.ndarray, list[str]]:
    """``(M, 3 + Z')``: the tool point and the kept landmarks' weights ``w (Z',)`` refitted without
    each demonstration in turn (module docstring), from the learned ``tool (3,)`` and ``w`` at the
    alignment ``align`` (one ``(S_m,)`` per demonstration), NaN where a refit diverged; and a line
    per such refit. ``workers`` refits at once in threads."""
    from lfd.learning.em import EM_FAILURES, EMFitter

    learn_tool, learn_env = cfg.tool == "learn", cfg.env == "learn" and len(kept) > 1

    def refit(m):
        others = [i for i in range(data.M) if i != m]
        t_idx = torch.as_tensor(np.concatenate([align[i] for i in others]), device=device)
        try:
            t_m, w_m = EMFitter(data.subset(others), cfg, dtype, device, kept).fit_zeta(
                tool, w, t_idx, learn_tool, learn_env, bound=False)
        except EM_FAILURES as e:
            return np.full(3 + len(kept), np.nan), f"the jackknife's refit without demonstration {m} failed: {e}"
        return np.concatenate([t_m.cpu().numpy(), w_m.cpu().numpy()]), None

    with ThreadPoolExecutor(max(1, min(workers, data.M)), thread_name_prefix="lfd-jackknife") as pool:
        out = list(pool.map(refit, range(data.M)))
    return np.stack([r for r, _ in out]), [f for _, f in out if f is not None]


def heldout_losses(data, cfg, dtype, device, landmarks, tool, w, align) -> np.ndarray:
    """``(M,)``: Eq. 3 summed over each demonstration's observations at its alignment ``align[m]``,
    under the zeta ``tool (3,)``, ``w (Z',)`` over the sensed landmarks ``landmarks`` and the
    per-step Gaussians (closed form, ``EMFitter.eta_from``) fitted to the other demonstrations."""
    from lfd.learning.em import EMFitter
    from lfd.learning.model import aligned_nll_tensor

    out = np.zeros(data.M)
    for m in range(data.M):
        others = [i for i in range(data.M) if i != m]
        t_idx = torch.as_tensor(np.concatenate([align[i] for i in others]), device=device)
        fitter = EMFitter(data.subset(others), cfg, dtype, device, landmarks)
        mu, sigma_inv = fitter.eta_from(tool, w, t_idx)
        held = data.subset([m])
        with torch.no_grad():
            f, _ = held.features(tool, w, held.T_lm_world[:, landmarks])
            out[m] = float(aligned_nll_tensor(f, torch.as_tensor(align[m], device=device), mu, sigma_inv,
                                              cfg.logdet_scale).sum())
    return out


def worse_needed(n: int, alpha: float = ALPHA) -> int:
    """The fewest of ``n`` demonstrations on which a model must be worse to be told worse: the least
    ``k`` with ``P(Binomial(n, 1/2) >= k) <= alpha`` (``n + 1``, never, when even ``n`` of ``n`` is
    not that rare: ``n <= 4`` at 5%)."""
    tail = 0.0
    for k in range(n, -1, -1):
        tail += math.comb(n, k) / 2.0 ** n
        if tail > alpha:
            return k + 1
    return 0


def landmark_evidence(data, cfg, dtype, device, tool, w, align, kept, names, learn_tool: bool,
                      workers: int = 1) -> dict:
    """Per sensed landmark ``(worse, counted, gap)`` (module docstring, ``Uncertainty.evidence``), or
    a line saying why its model failed (a diverged refit, ``lfd.learning.em.EM_FAILURES``),
    against the learned ``tool (3,)`` and ``w (Z',)`` over the landmarks ``kept`` at the alignment
    ``align``; each one-landmark model starts its tool point from ``tool`` (kept when the tool
    point is not learned); ``workers`` landmarks at once in threads."""
    from lfd.learning.em import EM_FAILURES, EMFitter

    t_idx = torch.as_tensor(np.concatenate(align), device=device)
    reference = heldout_losses(data, cfg, dtype, device, kept, tool, w, align)
    tied = TIED * np.asarray(data.lengths, dtype=float)  # (M,)
    w1 = torch.ones(1, dtype=dtype, device=device)

    def compare(z):
        if list(kept) == [z]:  # the learned model itself
            return 0, 0, 0.0
        try:
            tool_z = (EMFitter(data, cfg, dtype, device, [z]).fit_zeta(tool, w1, t_idx, True, False)[0]
                      if learn_tool else tool)
            d = heldout_losses(data, cfg, dtype, device, [z], tool_z, w1, align) - reference  # (M,)
        except EM_FAILURES as e:
            return f"the model of landmark {names[z]!r} alone failed: {e}"
        counted = np.abs(d) > tied
        return int((d > tied).sum()), int(counted.sum()), float(d.mean())

    with ThreadPoolExecutor(max(1, min(workers, len(names))), thread_name_prefix="lfd-evidence") as pool:
        return dict(zip(names, pool.map(compare, range(len(names)))))


def about_equal(evidence: dict) -> tuple[str, ...]:
    """The landmarks of ``evidence`` not told from the learned model, best first."""
    close = [n for n, (worse, counted, _gap) in evidence.items() if worse < worse_needed(counted)]
    return tuple(sorted(close, key=lambda n: evidence[n][2]))


def estimate_uncertainty(data, cfg, fitter, tool, w, align, names, kept, dtype, device,
                         workers: int = 1) -> Uncertainty:
    """The ``Uncertainty`` of the learned ``tool (3,)`` and kept weights ``w (Z',)`` (landmarks
    ``kept``, indices into ``names``) at the final alignment ``align`` (one ``(S_m,)`` per
    demonstration); ``fitter`` the ``EMFitter`` of the kept landmarks; ``workers`` refits at once."""
    t0 = time.perf_counter()
    learn_tool, learn_env = cfg.tool == "learn", cfg.env == "learn"
    weights_learned = learn_env and len(kept) > 1
    tool_cov, env_se = None, {}
    failures: list[str] = []
    if learn_tool or weights_learned:
        if data.M > 1:
            reps, failures = jackknife(data, cfg, dtype, device, tool, w, align, kept, workers)  # (M, 3 + Z')
            reps = reps[np.isfinite(reps).all(1)]
        else:  # one demonstration: nothing to resample
            reps = np.zeros((data.M, 3 + len(kept)))
        M = len(reps)
        C = reps - reps.mean(0)
        V = (M - 1) / M * (C.T @ C) if M > 1 else np.full((C.shape[1], C.shape[1]), np.inf)
        # the coordinates flat_coordinates covers: the learned ones
        covered = (list(range(3)) if learn_tool else []) + (list(range(3, 3 + len(kept))) if weights_learned else [])
        t_idx = torch.as_tensor(np.concatenate(align), device=device)
        diag = np.diagonal(V).copy()
        diag[covered] = np.where(flat_coordinates(fitter, tool, w, t_idx, learn_tool, weights_learned),
                                 np.inf, diag[covered])
        V[np.diag_indices_from(V)] = diag
        if learn_tool:
            tool_cov = V[:3, :3]
        if weights_learned:
            env_se = {names[k]: float(np.sqrt(V[3 + i, 3 + i])) for i, k in enumerate(kept)}
    evidence: dict = {}
    if learn_env and len(names) > 1 and data.M > 1:
        found = landmark_evidence(data, cfg, dtype, device, tool, w, align, kept, names, learn_tool, workers)
        failures += [v for v in found.values() if isinstance(v, str)]
        evidence = {n: v for n, v in found.items() if not isinstance(v, str)}
    return Uncertainty(tool_cov=tool_cov, env_se=env_se, evidence=evidence, about_equal=about_equal(evidence),
                       failures=tuple(failures), time_s=time.perf_counter() - t0)


def _cm(v) -> str:
    return "[" + ", ".join("undetermined" if not np.isfinite(x) else f"{100 * x:.1f}" for x in v) + "] cm"


def uncertainty_notes(unc: Uncertainty, tool: np.ndarray, weights: dict, cfg) -> list[str]:
    """The warnings of ``unc``: its failures, landmarks about equal (named, with the learned ``weights`` by name),
    and a learned ``tool (3,)`` beyond ``cfg.tool_size``: either the demonstrations cannot place it
    (its distance's standard error reaches back to the tool's size within ``Z_CRIT`` of them), or
    they place it there."""
    notes = [f"uncertainty: {f}" for f in unc.failures]
    if len(unc.about_equal) > 1:
        named = ", ".join(repr(n) for n in unc.about_equal)
        used = ", ".join(f"{n} {x:.2f}" for n, x in weights.items())
        n = max((counted for _w, counted, _g in unc.evidence.values()), default=0)
        why = (f"{n} demonstrations cannot tell any two landmarks apart (a landmark alone worse on all {n} is so "
               f"by chance {100 * 0.5 ** n:.0f}% of the time; {math.ceil(math.log2(1 / ALPHA))} are needed at "
               f"{100 * ALPHA:g}%)" if worse_needed(n) > n else
               f"held out one at a time, none of them alone is worse than the learned model on more "
               f"demonstrations than chance allows ({100 * ALPHA:g}%, a sign test)")
        notes.append(f"landmarks {named} explain the demonstrations about equally: {why}; the data cannot tell them "
                     f"apart, and the learned weights ({used}) are one choice among them; demonstrate with those "
                     f"landmarks placed independently of each other, or fix the landmark (--env manual)")
    if unc.tool_cov is not None:
        dist = float(np.linalg.norm(tool))
        if dist > cfg.tool_size:
            se_r = unc.radial_se(tool)
            where = (f"the learned tool point lies {dist:.2f} m from the gripper, beyond the tool's size "
                     f"({cfg.tool_size:g} m, FitConfig.tool_size)")
            if not Z_CRIT * se_r < dist - cfg.tool_size:
                se = "undetermined" if not math.isfinite(se_r) else f"{100 * se_r:.1f} cm"
                notes.append(f"{where}, and the demonstrations cannot place it: the standard error of that "
                             f"distance is {se} (per axis {_cm(unc.tool_se)}, gripper frame); turn the tool "
                             f"more while demonstrating, or fix the tool point (--tool manual)")
            else:
                notes.append(f"{where}; the demonstrations place it there (standard error {100 * se_r:.1f} cm): "
                             f"a tool longer than {cfg.tool_size:g} m, or a task point off the tool")
    return notes
