"""The EM machinery of ``lfd.learning.learn.fit``: the data as tensors, M-step (LBFGS), E-step (DTW).

``FitData`` holds everything that does not depend on zeta or eta (forward kinematics computed
once); ``EMFitter`` runs EM from one initial alignment (one restart of ``fit``). The objective
and the profiled M-step are described in ``lfd.learning.learn``'s docstring; shapes: ``N`` observations
of ``M`` demonstrations, ``T`` time steps, ``F = d + 3`` features (``d + 9`` with the attitude),
``Z`` landmarks.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import torch

from lfd.learning.dtw import dtw_align, dwell_limits
from lfd.learning.model import (
    aligned_nll_tensor,
    landmarks_inverse_tensor,
    step_nll_tensor,
    task_features_tensor,
    task_vectors_tensor,
)
from lfd.learning.priors import estimate_log_trans, floor_prior, volume_prior
from lfd.learning.tasks import TASK_VECTORS

__all__ = ["EM_FAILURES", "EMFitter", "FitData", "project_to_simplex"]

TOOL_BOUND_WEIGHT = 1e4  # per observation and m^2 beyond FitConfig.tool_radius: far steeper than any likelihood term

# what a restart that diverged raises (a non-finite loss, a covariance that is not positive definite)
EM_FAILURES = (FloatingPointError, torch.linalg.LinAlgError)


class FitData:
    """The demonstrations as tensors, and everything that does not depend on zeta or eta."""

    def __init__(self, demoset, kin, dtype, device, feature_set: str = "paper"):
        self.feature_set = feature_set
        self.vectors = TASK_VECTORS[feature_set]  # the task features' 3-vectors (point, then axes)
        self.n_task = 3 * self.vectors  # task features after the joint angles
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
        # landmark poses: one row per demonstration when every landmark held still in each
        # (Z, 4, 4), else one row per observation ((S, Z, 4, 4) tracked during the demonstration;
        # a demonstration with still landmarks repeats its poses); lm_row maps an observation to
        # its row, lm_demo a row to its demonstration, lm_counts the observations of each row
        poses = [np.asarray(d.landmarks) for d in demoset.demos]
        bad = [d.name or str(i) for i, (d, p) in enumerate(zip(demoset.demos, poses))
               if p.ndim == 4 and len(p) != d.n_samples]
        if bad:
            raise ValueError(f"demonstration(s) {bad}: tracked landmark poses need one pose per sample")
        self.moving = any(p.ndim == 4 for p in poses)
        if self.moving:
            lm = np.concatenate([p if p.ndim == 4 else np.broadcast_to(p, (n, *p.shape))
                                 for p, n in zip(poses, self.lengths)])  # (N, Z, 4, 4)
            self.lm_row = torch.arange(self.N, device=device)
            self.lm_demo = self.demo
            self.lm_counts = torch.ones(self.N, dtype=dtype, device=device)
        else:
            lm = np.stack(poses)  # (M, Z, 4, 4)
            self.lm_row = self.demo
            self.lm_demo = torch.arange(self.M, device=device)
            self.lm_counts = torch.tensor(self.lengths, dtype=dtype, device=device)
        self.T_lm_world = landmarks_inverse_tensor(torch.as_tensor(lm, dtype=dtype, device=device))  # (R, Z, 4, 4)

    def subset(self, demos) -> FitData:
        """The same data of the demonstrations ``demos`` (indices, in order; renumbered 0, 1, ...),
        the arrays sliced from these (no forward kinematics again)."""
        keep = torch.as_tensor(list(demos), dtype=self.demo.dtype, device=self.demo.device)
        new_index = torch.full((self.M,), -1, dtype=self.demo.dtype, device=self.demo.device)
        new_index[keep] = torch.arange(len(keep), dtype=self.demo.dtype, device=self.demo.device)
        order = torch.cat([(self.demo == m).nonzero().flatten() for m in keep.tolist()])  # (N',) in order
        rows = (torch.cat([(self.lm_demo == m).nonzero().flatten() for m in keep.tolist()]) if not self.moving
                else order)  # (R',)
        out = copy.copy(self)
        out.M = len(keep)
        out.lengths = [self.lengths[m] for m in keep.tolist()]
        out.N = sum(out.lengths)
        out.q, out.T_world_ee, out.sample = self.q[order], self.T_world_ee[order], self.sample[order]
        out.demo = new_index[self.demo[order]]
        out.lm_demo = new_index[self.lm_demo[rows]]
        out.lm_counts, out.T_lm_world = self.lm_counts[rows], self.T_lm_world[rows]
        out.lm_row = torch.arange(out.N, device=self.q.device) if self.moving else out.demo
        return out

    def features(self, tool, w, T_lm_world=None):
        """``f (N, F)`` and the linear parts ``A (R, 3, 3)`` of ``K_virt^-1`` per landmark row."""
        K = torch.einsum("z,rzij->rij", w, self.T_lm_world if T_lm_world is None else T_lm_world)
        x = task_features_tensor(task_vectors_tensor(self.T_world_ee, tool, self.feature_set),
                                 K[self.lm_row])  # (N, n_task)
        return torch.cat([self.q, x], dim=1), K[:, :3, :3]

    def pad(self, per_obs):
        """``(N, T)`` -> ``(M, S_max, T)`` (padding holds zeros)."""
        out = per_obs.new_zeros(self.M, max(self.lengths), per_obs.shape[1])
        out[self.demo, self.sample] = per_obs
        return out


class _Structure:
    """Which covariance entries a per-step Gaussian keeps: ``mask (F, F)`` 0/1, the distinct kept
    entries ``pairs`` (``i <= j``) and the fixed 0/1 map ``spread (m, F*F)`` of each onto
    ``(i, j)`` and ``(j, i)``."""

    def __init__(self, keep: torch.Tensor, dtype: torch.dtype):
        F = keep.shape[0]
        self.mask = keep.to(dtype)
        i, j = torch.triu_indices(F, F, device=keep.device)
        on = keep[i, j]
        self.pairs = (i[on], j[on])
        self.spread = torch.zeros(int(on.sum()), F * F, dtype=dtype, device=keep.device)  # (m, F*F)
        rows = torch.arange(len(self.pairs[0]), device=keep.device)
        self.spread[rows, self.pairs[0] * F + self.pairs[1]] = 1.0
        self.spread[rows, self.pairs[1] * F + self.pairs[0]] = 1.0


class EMFitter:
    def __init__(self, data: FitData, cfg, dtype, device, landmark_idx):
        self.data, self.cfg, self.dtype, self.device = data, cfg, dtype, device
        self.T, self.K = cfg.time_steps, len(cfg.offsets)
        d = data.q.shape[1]
        self.d, self.F = d, d + data.n_task
        self.T_lm = data.T_lm_world[:, landmark_idx]  # (R, Z', 4, 4)
        self.Z = len(landmark_idx)
        # each feature's group: the joints, the tool point, the attitude
        group = torch.tensor([0] * d + [1] * 3 + [2] * (data.n_task - 3), device=device)  # (F,)
        self.floor = torch.tensor([cfg.floor_joint, cfg.floor_task, cfg.floor_attitude],
                                  dtype=dtype, device=device)[group]  # (F,)
        self.nu = float(cfg.floor_weight) if cfg.floor_weight is not None else data.N / self.T
        self.s = float(cfg.logdet_scale)
        self.dwell = dwell_limits(data.lengths, self.T, cfg.max_dwell)  # (M,) or None
        if cfg.covariance == "block":  # each group its own block while zeta is learned
            same = group[:, None] == group[None, :]  # (F, F)
            self.cov = self.final_cov = _Structure(same, dtype)
            if data.n_task > 3:  # the model's final Gaussians: the tool point and the attitude in one block
                task = group > 0
                self.final_cov = _Structure(same | (task[:, None] & task[None, :]), dtype)
        else:
            self.cov = self.final_cov = _Structure(torch.ones(self.F, self.F, dtype=torch.bool, device=device), dtype)
        if self.Z > 1:  # orthonormal basis of {u : sum u = 0}
            Q, _ = torch.linalg.qr(torch.cat([torch.ones(self.Z, 1, dtype=dtype, device=device),
                                              torch.eye(self.Z, dtype=dtype, device=device)], 1))
            self.B = Q[:, 1:self.Z]
        else:
            self.B = torch.zeros(1, 0, dtype=dtype, device=device)

    # -- the environment weights
    def weights(self, w_ref, u):
        """The environment weights ``(Z,)`` at the coordinates ``u (Z-1,)`` about ``w_ref (Z,)`` in the
        sum-to-one plane, ``x = w_ref + B u``: 'simplex' (``FitConfig.env_weights``) the Euclidean
        projection of ``x`` onto the simplex (``project_to_simplex``: each weight in [0, 1], their
        sum 1, so their L1 norm is 1, Sec. IV-A); 'affine' ``x`` itself (sum 1, any sign). ``u = 0``
        gives ``w_ref`` (on the simplex when ``w_ref`` is).

        On each face of the simplex the projection is affine, so LBFGS keeps the affine form's
        conditioning, and a weight reaches 0 at a finite ``u``: on the powder set 15 objective
        evaluations per M-step (median; affine 13), where a softmax took 38 and ``v^2 / |v|^2`` 24,
        which made the restarts 1.6 times slower. A weight at 0 takes part again when the
        objective's gradient favours it (the projection's gradient passes at the boundary)."""
        x = w_ref + self.B @ u
        return x if self.cfg.env_weights == "affine" else project_to_simplex(x)

    def weights_at(self, w_ref, learn_env):
        """``u -> (Z,)``: ``weights(w_ref, u)`` when the weights are learned, else ``w_ref`` as it is."""
        if learn_env and self.Z > 1:
            return lambda u: self.weights(w_ref, u)
        return lambda u: w_ref

    def settle_weights(self, w):
        """``w (Z,)`` made to sum to 1 to rounding: rescaled on the simplex (no sign can change),
        shifted along the ones vector when affine."""
        return w - (w.sum() - 1) / self.Z if self.cfg.env_weights == "affine" else w / w.sum()

    # -- pieces of the objective
    def zeta_terms(self, tool, w, A, bound: bool = True):
        """The objective's terms in zeta alone: the volume prior, the tool-radius bound (unless
        ``bound`` is False: the data's terms alone, ``lfd.learning.uncertainty``), a ``zeta_prior``."""
        out = (volume_prior(A, self.data.lm_counts, self.data.vectors, self.s) if self.cfg.volume_prior
               else tool.new_zeros(()))
        excess = tool.norm() - self.cfg.tool_radius  # the tool point stays within the tool's size
        if bound and bool(excess > 0):  # (inside it the objective is the paper's, to the bit)
            out = out + TOOL_BOUND_WEIGHT * self.data.N * excess ** 2
        if self.cfg.zeta_prior is not None:
            out = out + self.cfg.zeta_prior(tool, w)
        return out

    def closed_form(self, f, t_idx, cov: _Structure | None = None):
        """Per-step ``mu (T, F)``, ``Sigma (T, F, F)``, counts ``n (T,)`` (eta-optimum for this zeta),
        the covariance restricted to ``cov`` (default: the structure zeta is learned with).

        Sums over the observations of each step are products with the one-hot ``E (T, N)``
        (``index_add_`` on CPU is an order of magnitude slower, forward and backward); the
        scatter matrices are one product with the products ``c_i c_j`` of the ``m`` distinct
        entries the covariance keeps (``i <= j`` within its blocks), ``(N, m)``, spread into
        ``(T, F, F)`` by a fixed 0/1 matrix: 'block' with the attitude keeps 55 of 256 entries
        (this was most of the learning time when done as ``(T, N, F)`` masks)."""
        cov = self.cov if cov is None else cov
        E = self._onehot(t_idx)
        n = E.sum(1)
        mu = (E @ f) / n.clamp(min=1)[:, None]
        c = f - mu[t_idx]  # (N, F)
        i, j = cov.pairs
        S = ((E @ (c[:, i] * c[:, j])) @ cov.spread).reshape(-1, self.F, self.F)  # (T, F, F)
        Psi = torch.diag(self.floor ** 2)
        Sigma = (S + self.nu * Psi) / (self.s * n.clamp(min=1))[:, None, None] * cov.mask
        return mu, Sigma, n

    def _onehot(self, t_idx):
        if getattr(self, "_onehot_key", None) is not t_idx:
            self._onehot_key = t_idx
            self._onehot_val = torch.nn.functional.one_hot(t_idx, self.T).T.to(self.dtype)  # (T, N)
        return self._onehot_val

    def profiled(self, tool, w, t_idx, bound: bool = True):
        """The objective at eta's closed-form optimum for this zeta and alignment (a scalar; with
        ``bound`` False without the tool-radius bound, ``zeta_terms``)."""
        f, A = self.data.features(tool, w, self.T_lm)
        _, Sigma, n = self.closed_form(f, t_idx)
        logdet = 2 * torch.log(torch.diagonal(torch.linalg.cholesky(Sigma), dim1=-2, dim2=-1)).sum(-1)
        return (self.s * n * (logdet + self.F)).sum() + self.zeta_terms(tool, w, A, bound)

    def eta_from(self, tool, w, t_idx, cov: _Structure | None = None):
        """The eta-optimum ``mu (T, F)``, ``sigma_inv (T, F, F)`` for this zeta and alignment, the
        covariance restricted to ``cov`` (default: the structure zeta is learned with; the
        model's final Gaussians use ``self.final_cov``)."""
        with torch.no_grad():
            f, _ = self.data.features(tool, w, self.T_lm)
            mu, Sigma, n = self.closed_form(f, t_idx, cov)
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
        """LBFGS on ``closure``'s objective; ``FloatingPointError`` (the restart fails) when it is NaN,
        or not finite where LBFGS starts: torch's line search then ended in an ``IndexError``
        (a ``zeta_prior`` returning NaN)."""
        opt = torch.optim.LBFGS(params, lr=1.0, max_iter=max_iter, history_size=self.cfg.solver.lbfgs_history,
                                tolerance_grad=self.cfg.solver.lbfgs_tol_grad, tolerance_change=1e-12,
                                line_search_fn="strong_wolfe")
        calls = 0

        def checked():
            nonlocal calls
            loss = closure()
            value = float(loss.detach())
            if math.isnan(value) or (calls == 0 and not math.isfinite(value)):
                prior = " (a zeta_prior or eta_prior that returns NaN or inf?)" if (
                    self.cfg.zeta_prior is not None or self.cfg.eta_prior is not None) else ""
                raise FloatingPointError(f"the M-step's objective is {value} at LBFGS evaluation {calls + 1}{prior}")
            calls += 1
            return loss

        opt.step(checked)

    def search_tool(self, tool, w, t_idx):
        """The best start for the tool point's LBFGS: ``tool`` or a point of a ``g^3`` grid
        spanning ``+-cfg.solver.tool_search`` m per axis (``g = cfg.solver.tool_grid``), by the profiled loss.

        The profiled loss is not convex in the tool point (on the pour set, fits from different
        starts ended 12 cm apart), so the local LBFGS starts from the grid's best point instead
        of from the restart's random guess alone; 126 loss evaluations, no gradients."""
        h, g = float(self.cfg.solver.tool_search), int(self.cfg.solver.tool_grid)
        if h <= 0 or g < 1:
            return tool
        axis = torch.linspace(-h, h, g, dtype=self.dtype, device=self.device) if g > 1 else tool.new_zeros(1)
        grid = torch.cartesian_prod(axis, axis, axis).reshape(-1, 3)  # (g^3, 3)
        best, best_loss = tool, math.inf
        with torch.no_grad():
            for cand in torch.cat([tool[None], grid]):
                try:
                    loss = float(self.profiled(cand, w, t_idx))
                except torch.linalg.LinAlgError:
                    continue
                if loss < best_loss:
                    best, best_loss = cand.clone(), loss
        return best

    def fit_zeta(self, tool, w, t_idx, learn_tool, learn_env, bound: bool = True):
        """zeta ``(tool (3,), w (Z,))`` minimizing the profiled objective at this alignment by LBFGS
        from ``tool``, ``w`` (each of the two only when it is learned; without the tool-radius bound
        when ``bound`` is False)."""
        N = self.data.N
        tool_p = tool.clone().requires_grad_(learn_tool)
        u = torch.zeros(self.B.shape[1], dtype=self.dtype, device=self.device, requires_grad=learn_env)
        params = [p for p, on in ((tool_p, learn_tool), (u, learn_env and self.Z > 1)) if on]
        weights = self.weights_at(w, learn_env)

        def closure():
            opt_zero(params)
            loss = self.profiled(tool_p, weights(u), t_idx, bound) / N
            if loss.requires_grad:
                loss.backward()
            return loss

        if params:
            self._lbfgs(params, closure, self.cfg.solver.lbfgs_max_iter)
        w_out = weights(u).detach()
        return tool_p.detach(), self.settle_weights(w_out) if learn_env and self.Z > 1 else w_out

    def m_step(self, tool, w, t_idx, learn_tool, learn_env):
        tool, w = self.fit_zeta(tool, w, t_idx, learn_tool, learn_env)
        mu, sigma_inv = self.eta_from(tool, w, t_idx)
        if self.cfg.solver.m_step == "joint" or self.cfg.eta_prior is not None:
            tool, w, mu, sigma_inv = self.joint_polish(tool, w, mu, sigma_inv, t_idx, learn_tool, learn_env)
        return tool, w, mu, sigma_inv

    def joint_polish(self, tool, w, mu, sigma_inv, t_idx, learn_tool, learn_env, cov: _Structure | None = None):
        """LBFGS over zeta and eta together (eta as mu, log-diagonal, strictly-lower part; the
        covariance restricted to ``cov``, default the structure zeta is learned with)."""
        N = self.data.N
        tool_p = tool.clone().requires_grad_(learn_tool)
        u = torch.zeros(self.B.shape[1], dtype=self.dtype, device=self.device, requires_grad=learn_env)
        mu_p = mu.clone().requires_grad_(True)
        logd = torch.log(torch.diagonal(sigma_inv, dim1=-2, dim2=-1)).clone().requires_grad_(True)
        low = torch.tril(sigma_inv, -1).clone().requires_grad_(True)
        lmask = torch.tril((self.cov if cov is None else cov).mask, -1)
        params = [mu_p, logd, low] + [p for p, on in ((tool_p, learn_tool), (u, learn_env and self.Z > 1)) if on]
        weights = self.weights_at(w, learn_env)

        def build():
            return low * lmask + torch.diag_embed(torch.exp(logd))

        def closure():
            opt_zero(params)
            loss = self.joint_loss(tool_p, weights(u), mu_p, build(), t_idx) / N
            loss.backward()
            return loss

        self._lbfgs(params, closure, self.cfg.solver.joint_max_iter)
        w = weights(u).detach()
        w = self.settle_weights(w) if learn_env and self.Z > 1 else w
        mu_out, sigma_inv_out = mu_p.detach(), build().detach()
        # a step no sample is aligned to keeps the copy eta_from gave it: only the floor prior
        # sees it in the joint loss, which LBFGS lowers by sending its sigma_inv to 0
        empty = torch.bincount(t_idx, minlength=self.T) == 0  # (T,)
        mu_out[empty], sigma_inv_out[empty] = mu[empty], sigma_inv[empty]
        return tool_p.detach(), w, mu_out, sigma_inv_out

    def final_eta(self, tool, w, mu, sigma_inv, align):
        """The model's Gaussians ``mu (T, F)``, ``sigma_inv (T, F, F)`` for the learned zeta and
        alignment: with the 'block' covariance and the attitude, the tool point and the attitude in
        one block (``final_cov``), so that the model says how the tool point's place varies with the
        gripper's attitude; otherwise the EM's own ``mu``, ``sigma_inv``, unchanged.

        zeta is learned with each its own block, where the tool point stays identifiable (in one
        block with the gripper's axes its offset ``A R tool`` would be absorbed by the regression);
        the alignment (the one the EM's state was fitted on, ``align``) and the transitions stay the EM's,
        and ``FitResult.final_loss`` is the EM's loss."""
        if self.final_cov is self.cov:
            return mu, sigma_inv
        t_idx = torch.as_tensor(np.concatenate(align), device=self.device)
        mu, sigma_inv = self.eta_from(tool, w, t_idx, self.final_cov)
        if self.cfg.solver.m_step == "joint" or self.cfg.eta_prior is not None:
            _, _, mu, sigma_inv = self.joint_polish(tool, w, mu, sigma_inv, t_idx, False, False, self.final_cov)
        return mu, sigma_inv

    def band_mask(self, align):
        """``(M, S_max, T)`` True where a step is more than ``cfg.band`` steps from ``align``
        (the restart's starting alignment), i.e. where the E-step may not put a sample."""
        centre = self.data.pad(torch.as_tensor(np.concatenate(align), device=self.device)[:, None].to(self.dtype))
        t = torch.arange(self.T, device=self.device, dtype=self.dtype)
        return (t[None, None, :] - centre).abs() > self.cfg.band

    def e_step(self, tool, w, mu, sigma_inv, log_trans, band=None):
        with torch.no_grad():
            f, _ = self.data.features(tool, w, self.T_lm)
            cost = self.data.pad(step_nll_tensor(f, mu, sigma_inv, self.s))  # (M, S_max, T)
            if band is not None:
                cost = cost.masked_fill(band, float("inf"))
            align, values = dtw_align(cost, self.data.lengths, -2.0 * log_trans, self.cfg.offsets, self.dwell)
        return align, values

    def total_loss(self, tool, w, mu, sigma_inv, values):
        """Negative log posterior per observation given the DTW values of the current alignment."""
        with torch.no_grad():
            _f, A = self.data.features(tool, w, self.T_lm)
            out = values.sum() + floor_prior(sigma_inv, self.floor, self.nu) + self.zeta_terms(tool, w, A)
            if self.cfg.eta_prior is not None:
                out = out + self.cfg.eta_prior(mu, sigma_inv)
        return float(out) / self.data.N

    def em(self, tool, w, align, learn_tool, learn_env, on_iter=None):
        """Alternate M and E steps from an initial alignment; returns the state and loss history.

        The state ``(tool, w, mu, sigma_inv, log_trans, align)`` holds one alignment: the one its
        parameters and transitions were fitted on. When the E-step repeats it, that is also the
        E-step's; when the EM stops on ``em_tol`` or ``max_em_iters``, the last E-step's newer
        alignment is dropped with it (the loss history, from that E-step's DTW values, is kept),
        so a model's Gaussians, transitions and reported alignment always belong together."""
        history, state = [], None
        band = self.band_mask(align) if self.cfg.band is not None else None
        for it in range(self.cfg.solver.max_em_iters):
            t_idx = torch.as_tensor(np.concatenate(align), device=self.device)
            log_trans = estimate_log_trans(align, self.T, self.cfg.offsets, self.cfg.trans_floor,
                                           self.dtype, self.device)
            if it == 0 and learn_tool:
                tool = self.search_tool(tool, w, t_idx)
            tool, w, mu, sigma_inv = self.m_step(tool, w, t_idx, learn_tool, learn_env)
            new_align, values = self.e_step(tool, w, mu, sigma_inv, log_trans, band)
            loss = self.total_loss(tool, w, mu, sigma_inv, values)
            if not math.isfinite(loss) or not all(torch.isfinite(x).all() for x in (tool, w, mu, sigma_inv)):
                raise FloatingPointError(f"non-finite loss at EM iteration {it + 1}")
            history.append(loss)
            state = (tool, w, mu, sigma_inv, log_trans, align)
            if on_iter is not None:
                on_iter(it, loss, state)
            same = all(np.array_equal(a, b) for a, b in zip(align, new_align))
            align = new_align
            if same or (len(history) > 1 and abs(history[-2] - history[-1]) < self.cfg.solver.em_tol):
                break
        return state, history


def project_to_simplex(x: torch.Tensor) -> torch.Tensor:
    """The Euclidean projection ``(Z,)`` of ``x (Z,)`` onto ``{w : w >= 0, sum w = 1}``:
    ``max(x - tau, 0)`` with ``tau`` from the sorted entries (Duchi et al., ICML 2008);
    differentiable almost everywhere (piecewise linear)."""
    s, _ = torch.sort(x, descending=True)
    excess = torch.cumsum(s, 0) - 1
    k = torch.arange(1, len(x) + 1, dtype=x.dtype, device=x.device)
    kept = (s - excess / k > 0).nonzero()  # the largest entry always is, unless x holds NaN
    if not len(kept):
        raise FloatingPointError(f"environment weights {x.tolist()} are not numbers")
    rho = int(kept.max())  # the entries kept: the rho + 1 largest
    return torch.clamp(x - excess[rho] / (rho + 1), min=0)


def opt_zero(params):
    for p in params:
        if p.grad is not None:
            p.grad = None
