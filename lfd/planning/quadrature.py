"""The quadrature of an edge's cost (paper Sec. V-B): the line integral of the step cost over a
straight joint-space motion, by the trapezoid rule over ``m`` sub-intervals::

    W[e, t] = (tau / dt) * (stay[t] + mean_s ell(q(s), t))

``lfd.planning.edgestore.EdgeStore`` keeps the nodes of every roadmap edge and calls these."""

from __future__ import annotations

import numpy as np

__all__ = ["MIN_QUAD_DT", "interior_points", "interior_sums", "trapezoid_costs"]

# s: the default spacing of an edge's quadrature nodes is the model's sampling interval, but no
# finer than this (the pour's 25 Hz): a model learned from 1 kHz recordings would otherwise
# prepare 40 times more nodes per edge (a powder roadmap at dt = 1 ms outgrew 22 GB of memory)
MIN_QUAD_DT = 0.04


def interior_points(Qa: np.ndarray, Qb: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Interior quadrature nodes of segments ``Qa -> Qb`` (E, d) with ``m (E,)`` sub-intervals:
    ``(P, d)`` points, edge by edge, and ``first (E,)``: each edge's first row (``m - 1`` rows each)."""
    n_in = m - 1
    first = np.cumsum(n_in) - n_in
    edge = np.repeat(np.arange(len(m)), n_in)
    frac = (np.arange(len(edge)) - first[edge] + 1) / m[edge]
    return Qa[edge] + (Qb[edge] - Qa[edge]) * frac[:, None], first


def interior_sums(ell_in: np.ndarray, first: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``(E, T)`` each edge's step costs summed over its interior nodes, from ``ell_in (P, T)``
    (edge by edge from ``first (E,)``, ``m - 1`` rows each)."""
    sums = np.zeros((len(m), ell_in.shape[1]))
    has = m > 1
    if has.any():
        sums[has] = np.add.reduceat(ell_in, first[has], axis=0)
    return sums


def trapezoid_costs(ell_a: np.ndarray, ell_b: np.ndarray, sums: np.ndarray, m: np.ndarray, tau: np.ndarray,
                    stay: np.ndarray, dt: float) -> np.ndarray:
    """``(E, T)`` edge costs from the step costs at the ends ``(E, T)`` and summed over the
    interior nodes ``sums (E, T)``, ``m``/``tau (E,)``, ``stay (T,)``."""
    mean = (0.5 * (ell_a + ell_b) + sums) / m[:, None]
    with np.errstate(invalid="ignore"):
        W = (tau / dt)[:, None] * (stay[None, :] + mean)
    W[np.isnan(W)] = np.inf  # tau = 0 at a step that forbids staying
    return W
