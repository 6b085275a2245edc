"""Priors of the task model and the transition estimate, all in Eq. 3 units (see lfd.learning.model).

Every prior here is ``-2 log p`` up to a constant, so it adds directly to the loss.

* **Variance floor** (on eta). Independent zero-mean Gaussian priors on every entry of
  ``sigma_inv_t`` with precision ``nu * floor_j^2`` for column ``j`` (half-Gaussian on the
  positive diagonal): a proper prior whose cost is ``nu * |sigma_inv_t diag(floor)|_F^2 =
  nu * tr(Psi Sigma_t^-1)`` with ``Psi = diag(floor^2)``. It is negligible for variances well
  above ``floor^2`` and grows as ``floor^2 / variance`` below it. With ``n_t`` observations at a
  step the optimum is ``Sigma_t = (S_t + nu Psi) / (s n_t)`` (``S_t`` the scatter, ``s`` the
  log-det scale), so ``Sigma_t >= nu / (s n_t) * Psi``: a floor that keeps every covariance
  positive-definite however few observations a step gets. ``nu`` defaults to the mean number
  of observations per step, which makes the floor ``Psi`` itself at an average step.
* **Volume** (on zeta). ``K_virt^-1`` has linear part ``A = sum_i env_i R_i^T``; when the
  landmark rotations differ, a mixture can have ``|det A| << 1`` and shrink every task feature
  (and its variance) towards zero, a degenerate optimum with loss -> -inf. Each of the ``k``
  3-vectors of the task features (the tool point; with 'attitude' also the gripper's two axes)
  goes through ``A``, which scales their volume by ``|det A|^k`` and the loss's ``s log|Sigma|``
  by ``2 s k log|det A|``; the volume prior ``-2 s k log|det A_m|`` per observation of
  demonstration ``m`` cancels exactly that change (it makes the likelihood that of the task
  vectors in an undistorted frame). It is zero when all landmark rotations agree (then
  ``A = (sum env) I = I``).
* **Transitions**: ``p(t + o_k | t)`` are the observed frequencies in the current alignments,
  each permitted one raised to ``floor`` and the row renormalized, K times (K the offsets): an
  entry raised ends at the floor less a hair of the renormalization (0.01 -> 0.009999 for two
  offsets); offsets that would leave the last step are forbidden (``log p = -inf``).
"""

from __future__ import annotations

import numpy as np
import torch

from lfd.learning.dtw import alignment_step_counts

__all__ = ["estimate_log_trans", "floor_prior", "volume_prior"]


def floor_prior(sigma_inv: torch.Tensor, floor: torch.Tensor, nu: float) -> torch.Tensor:
    """``nu * sum_t |sigma_inv_t diag(floor)|_F^2``; ``sigma_inv (T, F, F)``, ``floor (F,)`` stds."""
    return nu * ((sigma_inv * floor[None, None, :]) ** 2).sum()


def volume_prior(A: torch.Tensor, counts: torch.Tensor, vectors: int, logdet_scale: float) -> torch.Tensor:
    """``-2 s k sum_r counts_r log|det A_r|``; ``A (R, 3, 3)`` per landmark row (a demonstration, or
    an observation when landmarks were tracked), ``counts (R,)`` observations per row, ``k =
    vectors`` the task features' 3-vectors, ``s = logdet_scale``."""
    return -2.0 * logdet_scale * vectors * (counts * torch.linalg.slogdet(A)[1]).sum()


def _permitted(time_steps: int, offsets) -> np.ndarray:
    t = np.arange(time_steps)[:, None]
    return t + np.asarray(offsets)[None, :] <= time_steps - 1  # (T, K)


def estimate_log_trans(alignments, time_steps: int, offsets, floor: float = 0.01,
                       dtype=torch.float64, device="cpu") -> torch.Tensor:
    """Transition log-probabilities ``(T, K)`` from alignments, every permitted one at ``floor``
    or above it, less the last renormalization's hair (module docstring)."""
    ok = _permitted(time_steps, offsets)
    counts = alignment_step_counts(alignments, time_steps, offsets) * ok
    total = counts.sum(1, keepdims=True)
    p = np.where(total > 0, counts / np.maximum(total, 1), ok / ok.sum(1, keepdims=True))
    for _ in range(len(offsets)):  # K rounds of raising and renormalizing
        p = np.where(ok, np.maximum(p, floor), 0.0)
        p = p / p.sum(1, keepdims=True)
    with np.errstate(divide="ignore"):
        return torch.as_tensor(np.log(p), dtype=dtype, device=device)

