"""Learning a task model from demonstrations: EM with DTW (E-step) and LBFGS (M-step), Sec. IV.

The objective is the negative log posterior of Eq. 1 in Eq. 3 units (see ``lfd.model``):
``sum_obs [s log|Sigma_t| + |sigma_inv_t (f - mu_t)|^2] + sum_trans -2 log p(t'|t) + priors``
(priors in ``lfd.priors``). Losses reported per observation.

M-step. With alignments fixed, zeta and eta are estimated together. For the default priors
the eta-optimum for a given zeta is closed-form (per-step mean, ``Sigma_t = (S_t + nu Psi) /
(s n_t)``), so the M-step minimizes the *profiled* objective over zeta with LBFGS (variable
projection: the same joint minimum, in 3 + Z - 1 unknowns instead of ~1,600) and then sets eta
in closed form. ``m_step='joint'`` (forced when an ``eta_prior`` is given) continues with LBFGS
over zeta and eta together from there.

env weights are ``w = w_ref + B u`` with ``B (Z, Z-1)`` an orthonormal basis of ``{sum = 0}``
(the tangent space of the constraint, Sec. IV-A); weights may be negative. After each M-step
``w`` is re-projected to sum exactly to 1 (to rounding).

Segment fixed to the robot (start above the source): there any environmental frame looks
noisy, and an average of Z independent landmarks has 1/Z of the variance of one, which pulls
weights towards the average. Measured on synthetic sets with 2 of 8 steps fixed in the world
frame (``benchmarks/learning.py --compare``): with the default block covariance the true
landmark keeps 0.97-0.99 of the weight before pruning, the others fall under the 5% pruning
threshold and the refit uses the true landmark alone; the pull is real but small because the
steps relative to the bowl dominate the objective. Nothing else is done about it by default.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from lfd.dtw import dtw_align, min_samples, random_alignment
from lfd.model import (COVARIANCES, OFFSETS, TaskModel, aligned_nll_tensor, landmarks_inverse_tensor,
                       step_nll_tensor)
from lfd.priors import estimate_log_trans, floor_prior, volume_prior

__all__ = ["FitConfig", "FitResult", "fit", "TOOL_MODES", "ENV_MODES", "M_STEPS"]

TOOL_MODES = ("learn", "gripper", "tip")
ENV_MODES = ("learn", "bowl")
M_STEPS = ("profile", "joint")
DTYPES = {"float64": torch.float64, "float32": torch.float32}


@dataclass(frozen=True)
class FitConfig:
    """Settings of ``fit``. Lengths in metres, angles in radians, losses in Eq. 3 units.

    tool : 'learn' | 'gripper' (fixed at the end-effector origin) | 'tip' (task.manual_tool_point).
    env : 'learn' | 'bowl' (one-hot on task.reference_landmark).
    covariance : 'block' (default: joints independent of task features) | 'full' (the paper).
        With 'full', zeta enters the likelihood only through the task features' residual
        *given* the joints; as the tool point's world position is a smooth function of q,
        changing the tool point is largely absorbed by that regression and the tool point is
        nearly unidentifiable (measured: 17-45 cm error vs 0.5-2.2 cm for 'block' on synthetic
        data with known truth, see benchmarks/learning.py --compare).
    logdet_scale : ``s`` in ``s log|Sigma|`` (1 = maximum likelihood).
    floor_joint, floor_task : the variance-floor prior's standard deviations (lfd.priors).
    floor_weight : its pseudo-observations ``nu``; None = mean observations per time step.
    volume_prior : add ``-2 log|det A|`` per observation (lfd.priors); zero for aligned frames.
    trans_floor : smallest probability of a permitted transition.
    em_tol : stop when the per-observation loss changes less (or alignments repeat).
    num_threads : torch CPU threads during the fit (restored afterwards); the tensors are
        small, so one thread is fastest and immune to oversubscription; None leaves it alone.
    """

    time_steps: int = 24
    offsets: tuple[int, ...] = OFFSETS
    restarts: int = 4
    max_em_iters: int = 25
    em_tol: float = 1e-5
    lbfgs_max_iter: int = 50
    lbfgs_history: int = 20
    lbfgs_tol_grad: float = 1e-7
    joint_max_iter: int = 200
    tool: str = "learn"
    env: str = "learn"
    covariance: str = "block"
    m_step: str = "profile"
    prune_threshold: float = 0.05
    seed: int = 0
    device: str = "cpu"
    dtype: str = "float64"
    logdet_scale: float = 1.0
    floor_joint: float = 1e-3
    floor_task: float = 1e-3
    floor_weight: float | None = None
    volume_prior: bool = True
    trans_floor: float = 0.01
    num_threads: int | None = 1
    tool_init_std: float = 0.15
    zeta_prior: Callable | None = field(default=None, compare=False)
    eta_prior: Callable | None = field(default=None, compare=False)

    def __post_init__(self):
        for name, allowed in (("tool", TOOL_MODES), ("env", ENV_MODES), ("covariance", COVARIANCES),
                              ("m_step", M_STEPS), ("dtype", tuple(DTYPES)), ("device", ("cpu", "cuda"))):
            value = getattr(self, name)
            if value not in allowed and not (name == "device" and str(value).startswith("cuda:")):
                raise ValueError(f"FitConfig.{name} must be one of {', '.join(allowed)}; got {value!r}")
        if int(self.time_steps) < 2:
            raise ValueError(f"FitConfig.time_steps must be at least 2, got {self.time_steps}")
        if int(self.restarts) < 1:
            raise ValueError(f"FitConfig.restarts must be at least 1, got {self.restarts}")
        if sorted(set(self.offsets)) != sorted(self.offsets) or min(self.offsets) < 0 or 1 not in self.offsets:
            raise ValueError(f"FitConfig.offsets must be distinct, non-negative and include 1; got {self.offsets}")
        if not 0 <= self.prune_threshold < 1:
            raise ValueError(f"FitConfig.prune_threshold must be in [0, 1), got {self.prune_threshold}")
        if not 0 < self.trans_floor < 1.0 / len(self.offsets):
            raise ValueError(f"FitConfig.trans_floor must be in (0, 1/K), got {self.trans_floor}")


@dataclass(frozen=True)
class FitResult:
    """What ``fit`` found. Losses are per observation, Eq. 3 units (negative log posterior)."""

    model: TaskModel
    loss_history: tuple[tuple[float, ...], ...]  # per restart, then the refit after pruning
    em_iterations: tuple[int, ...]
    final_loss: float
    restart_losses: tuple[float, ...]  # nan for a dropped restart
    best_restart: int
    kept_landmarks: tuple[str, ...]
    env_before_pruning: dict
    alignments: tuple[np.ndarray, ...]
    virtual_det: tuple[float, ...]  # |det A| of K_virt^-1's linear part, per demonstration
    warnings: tuple[str, ...]
    timings: dict


class _Data:
    """The demonstrations as tensors, and everything that does not depend on zeta or eta."""

    def __init__(self, demoset, kin, dtype, device):
        self.M = len(demoset.demos)
        self.lengths = [d.n_samples for d in demoset.demos]
        self.N = sum(self.lengths)
        q = np.concatenate([d.q for d in demoset.demos])
        self.q = torch.as_tensor(q, dtype=dtype, device=device)  # (N, d)
        self.demo = torch.repeat_interleave(torch.arange(self.M, device=device),
                                            torch.tensor(self.lengths, device=device))  # (N,)
        self.sample = torch.cat([torch.arange(n, device=device) for n in self.lengths])  # (N,)
        with torch.no_grad():
            self.T_world_ee = kin.to(dtype, device).fk(self.q)  # (N, 4, 4), computed once
        lm = np.stack([d.landmarks for d in demoset.demos])  # (M, Z, 4, 4)
        self.T_lm_world = landmarks_inverse_tensor(torch.as_tensor(lm, dtype=dtype, device=device))
        self.counts = torch.tensor(self.lengths, dtype=dtype, device=device)

    def features(self, tool, w, T_lm_world=None):
        """``f (N, F)`` and the per-demo linear parts ``A (M, 3, 3)``."""
        K = torch.einsum("z,mzij->mij", w, self.T_lm_world if T_lm_world is None else T_lm_world)
        p_world = self.T_world_ee[:, :3, :3] @ tool + self.T_world_ee[:, :3, 3]  # (N, 3)
        Kn = K[self.demo]  # (N, 4, 4)
        x = torch.einsum("nij,nj->ni", Kn[:, :3, :3], p_world) + Kn[:, :3, 3]
        return torch.cat([self.q, x], dim=1), K[:, :3, :3]

    def pad(self, per_obs):
        """``(N, T)`` -> ``(M, S_max, T)`` (padding holds zeros)."""
        out = per_obs.new_zeros(self.M, max(self.lengths), per_obs.shape[1])
        out[self.demo, self.sample] = per_obs
        return out


class _Fitter:
    def __init__(self, data: _Data, cfg: FitConfig, dtype, device, landmark_idx):
        self.data, self.cfg, self.dtype, self.device = data, cfg, dtype, device
        self.T, self.K = cfg.time_steps, len(cfg.offsets)
        d = data.q.shape[1]
        self.d, self.F = d, d + 3
        self.T_lm = data.T_lm_world[:, landmark_idx]  # (M, Z', 4, 4)
        self.Z = len(landmark_idx)
        self.floor = torch.tensor([cfg.floor_joint] * d + [cfg.floor_task] * 3, dtype=dtype, device=device)
        self.nu = float(cfg.floor_weight) if cfg.floor_weight is not None else data.N / self.T
        self.s = float(cfg.logdet_scale)
        mask = torch.ones(self.F, self.F, dtype=dtype, device=device)
        if cfg.covariance == "block":
            mask[d:, :d] = 0
            mask[:d, d:] = 0
        self.mask = mask
        if self.Z > 1:  # orthonormal basis of {u : sum u = 0}
            Q, _ = torch.linalg.qr(torch.cat([torch.ones(self.Z, 1, dtype=dtype, device=device),
                                              torch.eye(self.Z, dtype=dtype, device=device)], 1))
            self.B = Q[:, 1:self.Z]
        else:
            self.B = torch.zeros(1, 0, dtype=dtype, device=device)

    # -- pieces of the objective
    def zeta_terms(self, tool, w, A):
        out = volume_prior(A, self.data.counts) if self.cfg.volume_prior else tool.new_zeros(())
        if self.cfg.zeta_prior is not None:
            out = out + self.cfg.zeta_prior(tool, w)
        return out

    def closed_form(self, f, t_idx):
        """Per-step ``mu (T, F)``, ``Sigma (T, F, F)``, counts ``n (T,)`` (eta-optimum for this zeta).

        Sums over the observations of each step are products with the one-hot ``E (T, N)``
        (``index_add_`` on CPU is an order of magnitude slower, forward and backward)."""
        E = self._onehot(t_idx)
        n = E.sum(1)
        mu = (E @ f) / n.clamp(min=1)[:, None]
        c = f - mu[t_idx]  # (N, F)
        S = (E[:, :, None] * c[None]).transpose(1, 2) @ c  # (T, F, F)
        Psi = torch.diag(self.floor ** 2)
        Sigma = (S + self.nu * Psi) / (self.s * n.clamp(min=1))[:, None, None] * self.mask
        return mu, Sigma, n

    def _onehot(self, t_idx):
        if getattr(self, "_onehot_key", None) is not t_idx:
            self._onehot_key = t_idx
            self._onehot_val = torch.nn.functional.one_hot(t_idx, self.T).T.to(self.dtype)  # (T, N)
        return self._onehot_val

    def profiled(self, tool, w, t_idx):
        f, A = self.data.features(tool, w, self.T_lm)
        _, Sigma, n = self.closed_form(f, t_idx)
        logdet = 2 * torch.log(torch.diagonal(torch.linalg.cholesky(Sigma), dim1=-2, dim2=-1)).sum(-1)
        return (self.s * n * (logdet + self.F)).sum() + self.zeta_terms(tool, w, A)

    def eta_from(self, tool, w, t_idx):
        with torch.no_grad():
            f, _ = self.data.features(tool, w, self.T_lm)
            mu, Sigma, n = self.closed_form(f, t_idx)
            empty = (n == 0).nonzero().flatten().tolist()
            full = (n > 0).nonzero().flatten()
            for t in empty:  # a step every demonstration skipped: copy the nearest step with data
                src = full[(full - t).abs().argmin()]
                mu[t], Sigma[t] = mu[src], Sigma[src]
            L = torch.linalg.cholesky(Sigma)
            eye = torch.eye(self.F, dtype=self.dtype, device=self.device).expand_as(L)
            return mu, torch.linalg.solve_triangular(L, eye, upper=False)

    def joint_loss(self, tool, w, mu, sigma_inv, t_idx):
        f, A = self.data.features(tool, w, self.T_lm)
        out = aligned_nll_tensor(f, t_idx, mu, sigma_inv, self.s).sum()
        out = out + floor_prior(sigma_inv, self.floor, self.nu) + self.zeta_terms(tool, w, A)
        if self.cfg.eta_prior is not None:
            out = out + self.cfg.eta_prior(mu, sigma_inv)
        return out

    # -- steps
    def _lbfgs(self, params, closure, max_iter):
        opt = torch.optim.LBFGS(params, lr=1.0, max_iter=max_iter, history_size=self.cfg.lbfgs_history,
                                tolerance_grad=self.cfg.lbfgs_tol_grad, tolerance_change=1e-12,
                                line_search_fn="strong_wolfe")
        opt.step(closure)

    def m_step(self, tool, w, t_idx, learn_tool, learn_env):
        N = self.data.N
        tool_p = tool.clone().requires_grad_(learn_tool)
        u = torch.zeros(self.B.shape[1], dtype=self.dtype, device=self.device, requires_grad=learn_env)
        params = [p for p, on in ((tool_p, learn_tool), (u, learn_env and self.Z > 1)) if on]

        def closure():
            opt_zero(params)
            loss = self.profiled(tool_p, w + self.B @ u, t_idx) / N
            if loss.requires_grad:
                loss.backward()
            return loss

        if params:
            self._lbfgs(params, closure, self.cfg.lbfgs_max_iter)
        tool, w = tool_p.detach(), (w + self.B @ u).detach()
        w = w - (w.sum() - 1) / self.Z
        mu, sigma_inv = self.eta_from(tool, w, t_idx)
        if self.cfg.m_step == "joint" or self.cfg.eta_prior is not None:
            tool, w, mu, sigma_inv = self.joint_polish(tool, w, mu, sigma_inv, t_idx, learn_tool, learn_env)
        return tool, w, mu, sigma_inv

    def joint_polish(self, tool, w, mu, sigma_inv, t_idx, learn_tool, learn_env):
        """LBFGS over zeta and eta together (eta as mu, log-diagonal, strictly-lower part)."""
        N = self.data.N
        tool_p = tool.clone().requires_grad_(learn_tool)
        u = torch.zeros(self.B.shape[1], dtype=self.dtype, device=self.device, requires_grad=learn_env)
        mu_p = mu.clone().requires_grad_(True)
        logd = torch.log(torch.diagonal(sigma_inv, dim1=-2, dim2=-1)).clone().requires_grad_(True)
        low = torch.tril(sigma_inv, -1).clone().requires_grad_(True)
        lmask = torch.tril(self.mask, -1)
        params = [mu_p, logd, low] + [p for p, on in ((tool_p, learn_tool), (u, learn_env and self.Z > 1)) if on]

        def build():
            return low * lmask + torch.diag_embed(torch.exp(logd))

        def closure():
            opt_zero(params)
            loss = self.joint_loss(tool_p, w + self.B @ u, mu_p, build(), t_idx) / N
            loss.backward()
            return loss

        self._lbfgs(params, closure, self.cfg.joint_max_iter)
        w = (w + self.B @ u).detach()
        return tool_p.detach(), w - (w.sum() - 1) / self.Z, mu_p.detach(), build().detach()

    def e_step(self, tool, w, mu, sigma_inv, log_trans):
        with torch.no_grad():
            f, _ = self.data.features(tool, w, self.T_lm)
            cost = self.data.pad(step_nll_tensor(f, mu, sigma_inv, self.s))  # (M, S_max, T)
            align, values = dtw_align(cost, self.data.lengths, -2.0 * log_trans, self.cfg.offsets)
        return align, values

    def total_loss(self, tool, w, mu, sigma_inv, values):
        """Negative log posterior per observation given the DTW values of the current alignment."""
        with torch.no_grad():
            f, A = self.data.features(tool, w, self.T_lm)
            out = values.sum() + floor_prior(sigma_inv, self.floor, self.nu) + self.zeta_terms(tool, w, A)
            if self.cfg.eta_prior is not None:
                out = out + self.cfg.eta_prior(mu, sigma_inv)
        return float(out) / self.data.N

    def em(self, tool, w, align, learn_tool, learn_env, on_iter=None):
        """Alternate M and E steps from an initial alignment; returns the state and loss history."""
        history, state = [], None
        for it in range(self.cfg.max_em_iters):
            t_idx = torch.as_tensor(np.concatenate(align), device=self.device)
            log_trans = estimate_log_trans(align, self.T, self.cfg.offsets, self.cfg.trans_floor,
                                           self.dtype, self.device)
            tool, w, mu, sigma_inv = self.m_step(tool, w, t_idx, learn_tool, learn_env)
            new_align, values = self.e_step(tool, w, mu, sigma_inv, log_trans)
            loss = self.total_loss(tool, w, mu, sigma_inv, values)
            if not math.isfinite(loss) or not all(torch.isfinite(x).all() for x in (tool, w, mu, sigma_inv)):
                raise FloatingPointError(f"non-finite loss at EM iteration {it + 1}")
            history.append(loss)
            state = (tool, w, mu, sigma_inv, log_trans, new_align)
            if on_iter is not None:
                on_iter(it, loss, state)
            same = all(np.array_equal(a, b) for a, b in zip(align, new_align))
            align = new_align
            if same or (len(history) > 1 and abs(history[-2] - history[-1]) < self.cfg.em_tol):
                break
        return state, history


def opt_zero(params):
    for p in params:
        if p.grad is not None:
            p.grad = None


def _resolve(cfg: FitConfig):
    if str(cfg.device).startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(f"FitConfig.device is {cfg.device!r} but torch.cuda.is_available() is False")
    return DTYPES[cfg.dtype], torch.device(cfg.device)


def fit(demoset, kin, config: FitConfig | None = None, callback=None) -> FitResult:
    """Learn a ``TaskModel`` from a ``DemoSet`` (Sec. IV).

    Parameters
    ----------
    demoset : lfd.demos.DemoSet (its ``ground_truth`` is never read).
    kin : lfd.kinematics.KinematicModel of ``demoset.robot`` (moved to the config's dtype/device).
    config : FitConfig (defaults when None).
    callback : called as ``callback(event: dict)`` after every EM iteration with keys
        ``stage`` ('restart' | 'refit'), ``restart``, ``iteration``, ``loss``, ``tool``, ``env``
        (numpy), ``landmarks`` (names), ``alignments``, ``features`` (N, F) tensor.

    Raises
    ------
    ValueError
        bad settings, demonstrations too short for the time steps, a mode that needs
        ``demoset.task`` without one, or every restart failing.
    """
    cfg = config or FitConfig()
    dtype, device = _resolve(cfg)
    threads = torch.get_num_threads()
    if cfg.num_threads is not None:
        torch.set_num_threads(int(cfg.num_threads))
    try:
        return _fit(demoset, kin, cfg, callback, dtype, device)
    finally:
        torch.set_num_threads(threads)


def _fit(demoset, kin, cfg, callback, dtype, device) -> FitResult:
    t0 = time.perf_counter()
    names = tuple(demoset.landmark_names)
    Z, T = len(names), cfg.time_steps
    need = min_samples(T, cfg.offsets)
    short = [d.name or str(i) for i, d in enumerate(demoset.demos) if d.n_samples < need]
    if short:
        raise ValueError(f"demonstration(s) {short} have fewer than {need} samples, too few for "
                         f"{T} time steps with offsets {cfg.offsets}")
    if cfg.tool == "tip" or cfg.env == "bowl":
        if demoset.task is None:
            raise ValueError(f"tool={cfg.tool!r}, env={cfg.env!r} need the demonstrations' task.json")
    data = _Data(demoset, kin, dtype, device)
    t_fk = time.perf_counter() - t0
    rng = np.random.default_rng(cfg.seed)
    torch.manual_seed(cfg.seed)
    notes: list[str] = []

    learn_tool, learn_env = cfg.tool == "learn", cfg.env == "learn"
    fixed_tool = {"gripper": (0.0, 0.0, 0.0), "tip": None, "learn": None}[cfg.tool]
    if cfg.tool == "tip":
        fixed_tool = demoset.task.manual_tool_point
    fixed_env = None
    if cfg.env == "bowl":
        fixed_env = np.zeros(Z)
        fixed_env[demoset.landmark_index(demoset.task.reference_landmark)] = 1.0

    def emit(stage, r, lm_names):
        def on_iter(it, loss, state):
            if callback is None:
                return
            tool, w, mu, sigma_inv, log_trans, align = state
            callback({"stage": stage, "restart": r, "iteration": it, "loss": loss,
                      "tool": tool.cpu().numpy(), "env": w.cpu().numpy(), "landmarks": lm_names,
                      "alignments": align, "mu": mu, "sigma_inv": sigma_inv})
        return on_iter

    fitter = _Fitter(data, cfg, dtype, device, list(range(Z)))
    histories, losses, iters, best = [], [], [], None
    for r in range(cfg.restarts):
        align = [random_alignment(n, T, rng, cfg.offsets) for n in data.lengths]
        if fixed_tool is not None:
            tool0 = np.asarray(fixed_tool, dtype=float)
        else:
            tool0 = np.zeros(3) if r == 0 else rng.normal(0.0, cfg.tool_init_std, 3)
        w0 = fixed_env if fixed_env is not None else (np.full(Z, 1.0 / Z) if r == 0 else rng.dirichlet(np.ones(Z)))
        try:
            state, hist = fitter.em(torch.as_tensor(tool0, dtype=dtype, device=device),
                                    torch.as_tensor(w0, dtype=dtype, device=device), align,
                                    learn_tool, learn_env, emit("restart", r, names))
        except (FloatingPointError, torch.linalg.LinAlgError) as e:
            notes.append(f"restart {r} dropped: {e}")
            warnings.warn(notes[-1], RuntimeWarning)
            histories.append(()), losses.append(float("nan")), iters.append(0)
            continue
        histories.append(tuple(hist)), losses.append(hist[-1]), iters.append(len(hist))
        if best is None or hist[-1] < losses[best[0]]:
            best = (r, state)
    if best is None:
        raise ValueError(f"every one of the {cfg.restarts} restarts failed: {'; '.join(notes)}")
    best_r, state = best
    t_restarts = time.perf_counter() - t0 - t_fk

    tool, w, mu, sigma_inv, log_trans, align = state
    env_before = {n: float(x) for n, x in zip(names, w.cpu().numpy())}
    kept = list(range(Z))
    final_loss = losses[best_r]
    if learn_env and Z > 1:
        kept = [i for i in range(Z) if abs(float(w[i])) >= cfg.prune_threshold]
        if not kept:
            kept = [int(w.abs().argmax())]
        if len(kept) < Z:
            fitter = _Fitter(data, cfg, dtype, device, kept)
            wk = w[kept] / w[kept].sum()
            try:
                state, hist = fitter.em(tool, wk, align, learn_tool, len(kept) > 1,
                                        emit("refit", best_r, tuple(names[i] for i in kept)))
                histories.append(tuple(hist)), iters.append(len(hist))
                tool, w, mu, sigma_inv, log_trans, align = state
                final_loss = hist[-1]
            except (FloatingPointError, torch.linalg.LinAlgError) as e:
                raise ValueError(f"refit after pruning to {[names[i] for i in kept]} failed: {e}") from e
    elif fixed_env is not None:
        kept = [int(np.argmax(fixed_env))]
        w = w[kept]
        fitter = _Fitter(data, cfg, dtype, device, kept)

    with torch.no_grad():
        _, A = data.features(tool, w, fitter.T_lm)
        det = torch.linalg.det(A).abs().cpu().numpy()
    if (det < 0.5).any() or (det > 2.0).any():
        notes.append(f"degenerate virtual landmark: |det A| of K_virt^-1 ranges {det.min():.3g}..{det.max():.3g} "
                     f"(1 for a rigid frame); the mixture shrinks or stretches the task features")
        warnings.warn(notes[-1], RuntimeWarning)
    kept_names = tuple(names[i] for i in kept)
    model = TaskModel(tool, w, mu, sigma_inv, log_trans, kept_names, demoset.robot, demoset.task,
                      all_landmark_names=names, offsets=cfg.offsets, covariance=cfg.covariance,
                      logdet_scale=cfg.logdet_scale,
                      options={"tool": cfg.tool, "env": cfg.env, "floor_joint": cfg.floor_joint,
                               "floor_task": cfg.floor_task, "floor_weight": fitter.nu,
                               "volume_prior": cfg.volume_prior, "trans_floor": cfg.trans_floor,
                               "m_step": cfg.m_step, "seed": cfg.seed})
    total = time.perf_counter() - t0
    return FitResult(model=model, loss_history=tuple(histories), em_iterations=tuple(iters),
                     final_loss=float(final_loss), restart_losses=tuple(losses), best_restart=best_r,
                     kept_landmarks=kept_names, env_before_pruning=env_before, alignments=tuple(align),
                     virtual_det=tuple(float(x) for x in det), warnings=tuple(notes),
                     timings={"fk_s": t_fk, "restarts_s": t_restarts,
                              "refit_s": total - t_fk - t_restarts, "total_s": total})
