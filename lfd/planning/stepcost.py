"""Step costs for the planner, split so that a landmark move costs milliseconds (paper Sec. V-B).

The planner's cost of holding configuration ``q`` at time step ``t`` is ``ell(q, t) >= 0``, the
learned negative log-likelihood in Eq. 3 units less its per-step floor (``lfd.learning.model``). Paths
touch the same configurations (roadmap vertices and the quadrature points of edges) before and
after a landmark moves; only the landmarks change. A ``StepCost`` therefore has two stages:

* ``prepare(Q: (N, d)) -> parts``: everything that does not depend on the landmarks, once per
  configuration (FK and the joint part of the features), a tuple of tensors with leading
  dimension ``N`` (parts of several calls are concatenated with ``torch.cat``);
* ``evaluate(parts, landmarks) -> (N, T)`` float64 numpy: the costs for these landmarks; may
  raise ``LookupError`` when a needed landmark is missing.

A step cost may also sum over runs of configurations before the landmarks are known (the
planner's edges integrate the cost over their quadrature nodes): ``prepare_sums(Q (N, d),
counts (E,)) -> parts`` for ``E`` consecutive runs of ``counts`` rows, or None when it cannot;
``evaluate_sums(parts, landmarks) -> (E, T)``, each run's summed cost. Without them the planner
evaluates every node (``CallableStepCost``).

``ModelStepCost`` (a learned ``TaskModel``). With the features ``f = [q; x]`` (Eq. 2), ``x (3k,)`` the
task features (the tool point in the virtual landmark frame, then with the ``'attitude'`` feature
set the gripper's axes there), and ``S_t = sigma_inv_t = [S_q | S_x]`` split into its
joint and task columns, the residual of Eq. 3 is ``r_t = a_t + S_x,t y_t`` with
``a_t = S_q,t (q - mu_q,t)`` (landmark-free) and ``y_t = x - mu_x,t``, so::

    |r_t|^2 = alpha_t + 2 beta_t . y_t + y_t^T G_t y_t,
    alpha_t = |a_t|^2,  beta_t = S_x,t^T a_t,  G_t = S_x,t^T S_x,t.

Written in ``x`` itself, ``|r_t|^2 = alpha'_t + 2 beta'_t . x + x^T G_t x`` with
``alpha'_t = alpha_t - 2 beta_t . mu_x,t + mu_x,t^T G_t mu_x,t`` and ``beta'_t = beta_t - G_t mu_x,t``.
``alpha' (N, T)``, ``beta' (N, T, 3k)`` and the world vectors ``P (N, k, 3)`` (the tool point, then
the axes) are prepared. With a block covariance (the learner's default: joints apart from the
task features) ``S_x,t^T S_q,t = 0``, so ``beta_t = 0`` and ``beta'_t = -G_t mu_x,t`` is the same
for every configuration: it is kept once, ``(T, 3k)``, not per configuration (on the pour's
roadmap, 160,000 quadrature nodes x 48 steps x 9, 0.5 GB). A landmark move recomputes ``x``
(``K_virt^-1`` applied to ``P``), one product for ``beta' . x`` and one matrix product ``(N, m)
@ (m, T)`` for the quadratic form over the ``m <= 3k (3k + 1) / 2`` distinct products ``x_i
x_j`` that some step weighs (45 with the tool point and the attitude in one block, the learner's
final Gaussians; 27 with the attitude in a block of its own; 6 for the tool point alone),
accumulated into one ``(N, T)`` result: for the paper's features (``k = 1``) about 20 flops per
configuration and step instead of FK plus an ``F x F`` triangular product.

Summed over a run of configurations (an edge's quadrature nodes), the cost needs only the run's
moments of the world vectors ``y = vec(P) (3k,)``: with ``x = A y + b`` (``A`` ``k`` copies of
``K_virt^-1``'s linear part, ``b`` its translation on the tool point), ``sum x x^T = n xbar xbar^T
+ A C A^T`` (``xbar = A ybar + b``, ``C`` the run's centred scatter of ``y``) and ``sum x = n
xbar``, so a landmark move costs one evaluation per edge, not per node (the pour's roadmap: 30,000
edges against 160,000 nodes). The scatter's share of the quadratic form is ``tr(G_t A C A^T) =
tr(H_t C)`` with ``H_t = A^T G_t A``: transforming the ``T`` weights, not the ``E`` scatters, keeps
``C``'s entries landmark-free (half the cost of a move with one task block). With joints and
task features coupled (``beta'`` per configuration) the sums do not separate and
``prepare_sums`` returns None.

``CallableStepCost`` adapts any ``factory(landmarks) -> step_nll(Q: (N, d)) -> (N, T)`` (a toy
cost, a user's own model) with a known lower bound ``floor`` (one number or ``(T,)``) subtracted.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np
import torch

from lfd.learning.model import TaskModel, task_features_tensor, task_vectors_tensor

__all__ = ["FK_BATCH", "CallableStepCost", "CostError", "ModelStepCost", "StepCost", "SummedStepCost"]

# configurations per forward-kinematics call over a roadmap's quadrature nodes (~160,000 for the
# pour): the FK's per-link intermediates of all of them at once took a gigabyte
FK_BATCH = 8192


class CostError(ValueError):
    """A step cost returned something unusable (wrong shape, NaN, below its floor)."""


class StepCost(Protocol):
    T: int

    def prepare(self, Q: np.ndarray) -> tuple[torch.Tensor, ...]: ...

    def evaluate(self, parts: tuple[torch.Tensor, ...], landmarks) -> np.ndarray: ...


@runtime_checkable
class SummedStepCost(StepCost, Protocol):
    """A ``StepCost`` that can also sum over runs of configurations (module docstring)."""

    def prepare_sums(self, Q: np.ndarray, counts: np.ndarray) -> tuple[torch.Tensor, ...] | None: ...

    def evaluate_sums(self, parts: tuple[torch.Tensor, ...], landmarks) -> np.ndarray: ...


def _upper_weights(M: torch.Tensor, i: torch.Tensor, j: torch.Tensor) -> torch.Tensor:
    """``(m, T)``: the entries ``(i, j)`` (``i <= j``) of symmetric ``M (T, n, n)``, off-diagonal ones
    doubled, so that ``v_i v_j @ out`` is the quadratic form ``v^T M_t v`` (or ``tr(M_t V)``)."""
    return (M[:, i, j] * torch.where(i == j, 1.0, 2.0).to(M)).T.contiguous()


def _checked(out, n: int, T: int, name: str) -> np.ndarray:
    out = np.asarray(out.detach().cpu() if torch.is_tensor(out) else out, dtype=float)
    if out.shape != (n, T):
        raise CostError(f"{name} must return shape ({n}, {T}), got {out.shape}")
    if np.isnan(out).any():
        raise CostError(f"{name} returned NaN")
    return out


class ModelStepCost:
    """The Mahalanobis term of Eq. 3 of a ``TaskModel`` (its ``step_nll`` less ``s log|Sigma_t|``).

    ``max_batch`` bounds the rows prepared at once (memory: ``max_batch * T * F`` numbers).
    Tensors live on the model's dtype and device; ``evaluate`` returns float64 numpy.
    """

    def __init__(self, model: TaskModel, max_batch: int = FK_BATCH):
        self.model, self.max_batch = model, int(max_batch)
        S = model.sigma_inv.detach()  # (T, F, F)
        mu = model.mu.detach()  # (T, F)
        self.T = mu.shape[0]
        self.d = d = model.dof
        self._S_q, self._S_x = S[:, :, :d], S[:, :, d:]  # (T, F, d), (T, F, 3k)
        self._mu_q, self._mu_x = mu[:, :d], mu[:, d:]  # (T, d), (T, 3k)
        G = self._S_x.transpose(1, 2) @ self._S_x  # (T, 3k, 3k)
        self._tool = model.tool.detach()  # (3,)
        self._Gmu = torch.einsum("tij,tj->ti", G, self._mu_x)  # (T, 3k)
        self._muGmu = (self._mu_x * self._Gmu).sum(-1)  # (T,)
        i, j = torch.triu_indices(G.shape[1], G.shape[1], device=G.device)  # the distinct products x_i x_j,
        used = (G[:, i, j] != 0).any(0)  # less those no step weighs (across a block covariance's blocks)
        i, j = i[used], j[used]
        self._pairs = (i, j)
        self._Gtri = _upper_weights(G, i, j)  # (m, T)
        # the summed cost's scatter term tr(G_t A C A^T) = tr(H_t C), H_t = A^T G_t A: weighed over
        # the products within the 3 x 3 blocks of world vectors that some step couples (A maps
        # each vector alone, so H_t is zero outside them); C's products are then landmark-free
        k = G.shape[1] // 3
        coupled3 = (G.reshape(self.T, k, 3, k, 3) != 0).any(4).any(2).any(0)  # (k, k)
        ci, cj = torch.triu_indices(3 * k, 3 * k, device=G.device)
        keep = coupled3[ci // 3, cj // 3]
        self._G, self._cpairs = G, (ci[keep], cj[keep])
        # joints and task features coupled (a full covariance): beta' per configuration; else one
        # (T, 3k) for all (block covariances: S_x^T S_q = 0)
        coupled = bool((self._S_x.transpose(1, 2) @ self._S_q != 0).any())
        self._beta_all = None if coupled else (-self._Gmu).T.contiguous()  # (3k, T); None: coupled

    def prepare(self, Q) -> tuple[torch.Tensor, ...]:
        """``Q (N, d)`` -> world vectors ``P (N, k, 3)``, ``alpha' (N, T)`` and, when joints and
        task features are coupled, ``beta' (N, T, 3k)``."""
        m = self.model
        Q = torch.as_tensor(np.array(Q, dtype=float), dtype=m.dtype, device=m.device).reshape(-1, self.d)
        N, n = len(Q), self._mu_x.shape[1]
        P = Q.new_empty(N, n // 3, 3)
        alpha = Q.new_empty(N, self.T)
        beta = Q.new_empty(N, self.T, n) if self._beta_all is None else None  # coupled: per configuration
        with torch.no_grad():
            for s in range(0, N, self.max_batch):  # filled in place: no second copy of the parts
                rows = slice(s, min(s + self.max_batch, N))
                Qb = Q[rows]
                P[rows] = task_vectors_tensor(m.kin.fk(Qb), self._tool, m.feature_set)
                a = torch.einsum("tfd,btd->btf", self._S_q, Qb[:, None, :] - self._mu_q[None])  # (B, T, F)
                alpha[rows] = (a * a).sum(-1) + self._muGmu
                if beta is not None:
                    b = torch.einsum("tfi,btf->bti", self._S_x, a)  # (B, T, 3k)
                    alpha[rows] -= 2.0 * (b * self._mu_x).sum(-1)
                    beta[rows] = b - self._Gmu
        return (P, alpha) if beta is None else (P, alpha, beta)

    def evaluate(self, parts, landmarks) -> np.ndarray:
        """``(N, T)`` Mahalanobis terms for ``landmarks (Z, 4, 4)`` (the model's kept ones)."""
        P, alpha = parts[0], parts[1]
        K = self.model.K_virt_inv(landmarks).detach()  # (4, 4)
        i, j = self._pairs
        with torch.no_grad():  # one (N, T) result, accumulated in place (each fresh (N, T) temporary
            # of a pour roadmap, 60 MB, costs its page faults: the evaluation took twice as long)
            x = task_features_tensor(P, K)  # (N, 3k)
            out = torch.addmm(alpha, x[:, i] * x[:, j], self._Gtri)  # alpha' + quadratic form, (N, T)
            if self._beta_all is None:  # coupled: beta' per configuration
                out += 2.0 * torch.bmm(parts[2], x[:, :, None])[..., 0]
            else:
                out.addmm_(x, self._beta_all, alpha=2.0)
            out.clamp_min_(0.0)
        return _checked(out, len(P), self.T, "ModelStepCost")

    def prepare_sums(self, Q, counts) -> tuple[torch.Tensor, ...] | None:
        """Moments of ``E`` runs of ``counts (E,)`` consecutive rows of ``Q (N, d)``: ``n (E,)``,
        the mean ``ybar (E, 3k)`` of the world vectors, the entries ``(E, m')`` of their centred
        scatter ``C`` that ``evaluate_sums`` weighs, and ``sum alpha' (E, T)``; None with joints and
        task features coupled (module docstring)."""
        if self._beta_all is None:
            return None
        m = self.model
        Q = np.asarray(Q, dtype=float).reshape(-1, self.d)
        counts = np.asarray(counts, dtype=np.int64).reshape(-1)
        if counts.sum() != len(Q) or (counts < 0).any():
            raise ValueError(f"counts must be >= 0 and sum to the {len(Q)} rows of Q, got {counts.sum()}")
        E, n3 = len(counts), self._mu_x.shape[1]
        owner = torch.as_tensor(np.repeat(np.arange(E), counts), device=m.device)  # (N,) each row's run
        n = torch.as_tensor(counts, dtype=m.dtype, device=m.device)
        y = n.new_empty(len(Q), n3)
        alpha_sum = n.new_zeros(E, self.T)
        batches = [slice(s, min(s + self.max_batch, len(Q))) for s in range(0, len(Q), self.max_batch)]
        for rows in batches:
            P, alpha = self.prepare(Q[rows])
            y[rows] = P.reshape(len(P), n3)
            alpha_sum.index_add_(0, owner[rows], alpha)
        ybar = n.new_zeros(E, n3).index_add_(0, owner, y) / n.clamp_min(1.0)[:, None]
        ci, cj = self._cpairs
        Ctri = n.new_zeros(E, len(ci))
        for rows in batches:  # centred: the world vectors' mean is metres, their spread centimetres
            dy = y[rows] - ybar[owner[rows]]
            Ctri.index_add_(0, owner[rows], dy[:, ci] * dy[:, cj])
        return n, ybar, Ctri, alpha_sum

    def evaluate_sums(self, parts, landmarks) -> np.ndarray:
        """``(E, T)``: each run's Mahalanobis terms summed over its rows (``prepare_sums``'s parts)."""
        n, ybar, Ctri, alpha_sum = parts
        if self._beta_all is None:
            raise ValueError("evaluate_sums: this model couples joints and task features; prepare_sums gave None")
        K = self.model.K_virt_inv(landmarks).detach()  # (4, 4)
        k = ybar.shape[1] // 3
        i, j = self._pairs
        ci, cj = self._cpairs
        with torch.no_grad():
            xbar = task_features_tensor(ybar.reshape(-1, k, 3), K)  # (E, 3k)
            A = torch.block_diag(*[K[:3, :3]] * k)  # (3k, 3k)
            H = A.T @ self._G @ A  # (T, 3k, 3k)
            nx = n[:, None] * xbar  # (E, 3k) sum x
            out = torch.addmm(alpha_sum, nx[:, i] * xbar[:, j], self._Gtri)  # n xbar^T G_t xbar
            out.addmm_(Ctri, _upper_weights(H, ci, cj))  # + tr(H_t C)
            out.addmm_(nx, self._beta_all, alpha=2.0)
            out.clamp_min_(0.0)
        return _checked(out, len(n), self.T, "ModelStepCost")


class CallableStepCost:
    """``factory(landmarks) -> step_nll``, ``step_nll(Q (N, d)) -> (N, T)``, less ``floor``.

    ``floor``: a lower bound of ``step_nll`` (one number or ``(T,)``); a value below it raises
    ``CostError`` (the planner needs non-negative costs). ``factory`` may raise ``LookupError``.
    """

    def __init__(self, factory: Callable, T: int, floor=0.0):
        self.factory, self.T = factory, int(T)
        self.floor = np.broadcast_to(np.asarray(floor, dtype=float), (self.T,)).copy()
        if not np.isfinite(self.floor).all():
            raise ValueError(f"floor must be finite, got {floor!r}")

    def prepare(self, Q) -> tuple[torch.Tensor]:
        Q = np.array(Q, dtype=float)
        return (torch.as_tensor(Q if Q.ndim == 2 else Q.reshape(len(Q), -1)),)  # (N, d); N may be 0

    def evaluate(self, parts, landmarks) -> np.ndarray:
        (Q,) = parts
        if len(Q) == 0:  # no configuration (edges without interior nodes): the callable is not asked
            return np.zeros((0, self.T))
        out = _checked(self.factory(landmarks)(Q), len(Q), self.T, "step_nll") - self.floor
        if (out < -1e-9 * np.maximum(1.0, np.abs(self.floor))).any():
            raise CostError(f"step_nll went below its floor by {-out.min():.3g}: floor is not a lower bound")
        return np.maximum(out, 0.0)
