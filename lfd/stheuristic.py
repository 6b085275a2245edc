"""A consistent A* heuristic for the spatiotemporal roadmap: cost-to-go of a relaxed problem.

Relaxation: a roadmap edge ``u-w`` at step t really costs
``(tau/dt) * (-log p(t|t) + mean ell along the edge)``, the mean being the trapezoid rule on
``m`` sub-intervals; the relaxed problem drops the interior nodes (ell >= 0) and keeps
``w_uw(t) = (tau/dt) * (-log p(t|t) + (ell(u, t) + ell(w, t)) / (2 m))`` (exact when m = 1), and
keeps every time edge exactly. Its
cost-to-go ``H(v, t)`` is a lower bound of the true one. We compute lower bounds ``G_j <= H``
backwards over t, vectorized over all vertices:

* ``G(v, T-1) = 0``;
* ``term(v, t) = min_k [-log p(t+k|t) + ell(v, t+k) + skip_k(v, t) + G(v, t+k)] + D_t ell(v, t) + s_t``
  (advance time at v first). Only with ``lfd.stcost``'s expected or occupancy dwell: ``D_t ell(v, t) + s_t``
  is the stay in step t, ``skip_k(v, t) = sum_j [(1 + D_j) ell(v, j) + s_j]`` over the steps
  ``t < j < t + k`` a time edge skips; without it both are zero;
* ``G_0(v, t) = h(t)`` (the vertex-independent bound below), then ``sweeps`` times
  ``G_j(v, t) = min(term(v, t), min_u [w_vu(t) + G_{j-1}(u, t)])`` (move first).

``h(t)`` is the cheapest way to advance from t to T-1 through the cheapest vertex of every step.
By induction ``h <= G_0 <= G_1 <= ... <= H``, and ``G_j(v) <= w_vu + G_{j-1}(u) <= c_vu + G_j(u)``
for every roadmap edge and ``G(v, t) <= term(v, t) <= c + G(v, t+k)`` for every time edge, so each
``G_j`` is **consistent** (networkx's A*, which never re-expands a node, stays optimal). More
sweeps tighten the bound (fewer expansions) at O(sweeps * T * edges) numpy work per landmark
update. The relaxed graph may contain edges later found to collide: extra edges only lower it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["time_only_bound", "relaxed_cost_to_go", "source_bound", "dwell_charge"]


def dwell_charge(ell_at, t: int, k: int, dwell):
    """What a time edge ``t -> t + k`` adds for the stays it implies (``lfd.stcost``'s expected
    dwell): ``D_t ell(t) + s_t`` for the step it leaves and ``(1 + D_j) ell(j) + s_j`` for each
    step ``t < j < t + k`` it skips. ``ell_at(j)`` gives the step cost at step j (a number or an
    array over vertices); ``dwell = (D (T,), s (T,))``, or None for no charge (0.0)."""
    if dwell is None:
        return 0.0
    D, s = dwell
    out = D[t] * ell_at(t) + s[t] if D[t] > 0 else 0.0  # (no 0 * inf)
    for j in range(t + 1, t + k):
        out = out + (1.0 + D[j]) * ell_at(j) + s[j]
    return out


def time_only_bound(trans: np.ndarray, min_ell: np.ndarray, offsets, dwell=None) -> np.ndarray:
    """``h: (T,)``: trans (T, K') with trans[t, k] = -log p(t+k|t) (inf = forbidden), min_ell (T,)
    the cheapest vertex cost per step, offsets the time offsets k > 0, dwell ``(D, s)`` the
    charge ``D_t ell + s_t`` of leaving step t (None: none)."""
    T = len(min_ell)
    h = np.full(T, np.inf)
    h[-1] = 0.0
    for t in range(T - 2, -1, -1):
        for k in offsets:
            if t + k < T:
                extra = dwell_charge(min_ell.__getitem__, t, k, dwell)
                h[t] = min(h[t], trans[t, k] + min_ell[t + k] + h[t + k] + extra)
    return h


def relaxed_cost_to_go(ell: np.ndarray, trans: np.ndarray, offsets, dt: float, src: np.ndarray,
                       dst: np.ndarray, tau: np.ndarray, m: np.ndarray, sweeps: int,
                       extra=None, t_min: int = 0, dwell=None) -> np.ndarray:
    """``G: (N, T)`` consistent lower bounds of the cost-to-go of every vertex and step.

    Parameters
    ----------
    ell : (N, T) shifted step cost of every vertex (roadmap vertices and temporary ones).
    trans : (T, K') -log transition probabilities by offset (column 0: stay).
    offsets : time offsets k > 0.
    src, dst, tau, m : (M,) directed edges (both directions of every roadmap edge) sorted by
        ``src``, their traversal times (s) and quadrature sub-intervals.
    sweeps : number of move-first relaxations per step (0: ``G = h`` for every vertex).
    extra : optional (src, dst, tau, m) of further directed edges, in any order (e.g. into a
        goal).
    t_min : steps before it (that a search starting at t_min never reaches) get ``G = h``,
        which keeps G consistent everywhere.
    dwell : ``(D (T,), s (T,))``, the charge ``D_t ell(v, t) + s_t`` of a time edge leaving step
        t at v (``lfd.stcost``'s expected or occupancy dwell); None = none.
    """
    N, T = ell.shape
    h = time_only_bound(trans, ell.min(axis=0), offsets, dwell)
    ellT = np.ascontiguousarray(ell.T)  # (T, N): contiguous rows per step
    GT = np.zeros((T, N))
    GT[:t_min] = h[:t_min, None]
    starts = np.searchsorted(src, np.arange(N))  # first out-edge of each vertex
    has = np.bincount(src, minlength=N) > 0 if len(src) else np.zeros(N, dtype=bool)
    first = starts[has]
    half_inv_m = 0.5 / m
    tau_dt = tau / dt
    for t in range(T - 2, t_min - 1, -1):
        term = np.full(N, np.inf)
        for k in offsets:
            if t + k < T and np.isfinite(trans[t, k]):
                c = trans[t, k] + ellT[t + k] + GT[t + k] + dwell_charge(ellT.__getitem__, t, k, dwell)
                term = np.minimum(term, c)
        g = np.minimum(term, h[t])
        stay = trans[t, 0]
        if sweeps and np.isfinite(stay) and (len(src) or extra is not None):
            e = ellT[t]
            w = tau_dt * (stay + (e[src] + e[dst]) * half_inv_m)
            if extra is not None:
                xs, xd, xt, xm = extra
                xw = (xt / dt) * (stay + (e[xs] + e[xd]) / (2 * xm))
            for _ in range(sweeps):
                g_new = term.copy()
                if len(first):
                    g_new[has] = np.minimum(term[has], np.minimum.reduceat(w + g[dst], first))
                if extra is not None:
                    np.minimum.at(g_new, xs, xw + g[xd])
                g = g_new
        if not np.isfinite(stay):
            g = term  # no moving at this step: advancing at v is the only option
        GT[t] = g
    return GT.T


def source_bound(ell_s: np.ndarray, G: np.ndarray, ell: np.ndarray, nbrs: np.ndarray,
                 tau: np.ndarray, m: np.ndarray, trans: np.ndarray, offsets,
                 dt: float, dwell=None) -> np.ndarray:
    """``(T,)`` consistent bound for a vertex with out-edges only (the robot's configuration).

    ell_s : (T,) its shifted step cost; G, ell : (N, T) from/as given to ``relaxed_cost_to_go``;
    nbrs : (E,) rows of G it has edges to, with traversal times tau and sub-intervals m (E,). One
    move-first relaxation on top of the final G, so ``G_s <= w + G[u]`` for its edges and
    ``G_s(t) <= c + G_s(t + k)`` in time. dwell: as for ``relaxed_cost_to_go``.
    """
    T = len(ell_s)
    g = np.zeros(T)
    for t in range(T - 2, -1, -1):
        term = min((trans[t, k] + ell_s[t + k] + g[t + k] + dwell_charge(ell_s.__getitem__, t, k, dwell)
                    for k in offsets if t + k < T), default=np.inf)
        w = (tau / dt) * (trans[t, 0] + (ell_s[t] + ell[nbrs, t]) / (2 * m))
        move = np.min(w + G[nbrs, t]) if len(nbrs) else np.inf
        g[t] = min(term, move)
    return g
