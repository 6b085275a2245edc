"""Search of the spatiotemporal roadmap (paper Sec. V-A, Fig. 3; Sec. V-B).

The product graph of the roadmap and the task's time steps has a node ``(v, t)`` per vertex and
step and two kinds of edges:

* time edges ``(v, t) -> (v, t + k)`` for the permitted offsets ``k > 0``, cost
  ``trans[t, k] + ell[v, t + k]`` (``trans[t, k] = -log p(t + k | t)`` in the step cost's units);
* spatial edges ``(a, t) -> (b, t)`` for the directed edges ``a -> b`` of a ``SearchGraph`` (both
  directions of every roadmap edge not known to collide, plus one-way edges of temporary
  vertices: the robot's configuration is a source, a goal configuration a sink), cost
  ``W[row, t]`` (``lfd.planning.edgestore``).

It is never materialized (~n T k edges: 1M at n = 1,000, T = 24). Two pieces search it:

* ``cost_to_go``: the exact cost-to-go ``H (N, T)`` of every node, backwards over the steps: a
  node's best way out of step t by a time edge, ``term(v) = min_k trans[t, k] + ell[v, t + k] +
  H[v, t + k]``, then the best way to some node's ``term`` inside step t, which is a shortest
  path problem on the roadmap with one super source (Dijkstra, scipy's compiled
  ``csgraph.dijkstra``, one call per step);
* ``astar``: A* from the robot's node with ``H`` as the heuristic. On the graph ``H`` was
  computed for, A* expands little more than the optimal path; after the planner drops edges
  found in collision, ``H`` of the larger graph is still a consistent lower bound, so A* stays
  optimal and explores only around the dropped edges. It reads the roadmap through networkx's
  public adjacency (``graph.adj[v]`` and its ``eid`` attributes, cached as arrays); running
  ``nx.astar_path`` itself would need the product graph materialized (17 s and 320 MB at
  n = 1,000, measured) or networkx's internals overridden (docs/DESIGN.md).
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field

import networkx as nx
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

__all__ = ["SearchBudgetExceeded", "SearchGraph", "astar", "cost_to_go", "transition_table"]

_BIG = 1e300  # stands for +inf inside scipy's Dijkstra


class SearchBudgetExceeded(RuntimeError):
    """The search expanded more product nodes than allowed."""


def transition_table(trans_cost: np.ndarray, offsets) -> np.ndarray:
    """``(T, max(offsets) + 1)`` cost of the transition ``t -> t + k`` (inf where not permitted
    or past the last step) from ``trans_cost (T, K)`` over ``offsets``."""
    tc = np.asarray(trans_cost, dtype=float)
    offsets = [int(k) for k in offsets]
    T = len(tc)
    trans = np.full((T, max(offsets) + 1), np.inf)
    for i, k in enumerate(offsets):
        trans[:, k] = tc[:, i]
    trans[~np.isfinite(trans)] = np.inf
    for k in range(trans.shape[1]):
        trans[max(T - k, 0):, k] = np.inf
    return trans


@dataclass
class SearchGraph:
    """The spatial edges of one plan's product graph, over ``N`` vertices with step costs
    ``ell (N, T)``: rows ``0..E-1`` of ``W (E + E_tmp, T)`` are the roadmap's edges (their ids,
    ``eid``), both directions; rows from ``E`` on are one-way edges ``src -> dst`` of the plan's
    temporary vertices (ids ``>= roadmap.n``: the robot's configuration is a source, a goal a
    sink). ``graph``: the roadmap's ``networkx.Graph``, read through its public adjacency
    (``graph.adj[v]``, attribute ``eid``) by the A* search; ``ends (E, 2)``: the same edges as an
    array, for the cost-to-go. ``goal``: a sink vertex that must be reached at the last step
    (None: any vertex at the last step ends the task); ``blocked (len(W),)``: rows known to
    collide, skipped by both searches (the caller may set more between searches);
    ``adjacency``: a cache ``{v: (neighbours, rows)}`` of the roadmap's adjacency that the caller
    may keep across plans while the roadmap's edges stay the same (filled as A* reads it)."""
    graph: nx.Graph
    ends: np.ndarray
    src: np.ndarray
    dst: np.ndarray
    W: np.ndarray
    ell: np.ndarray
    goal: int | None = None
    blocked: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    adjacency: dict = field(default_factory=dict)

    def __post_init__(self):
        if len(self.blocked) == 0:  # none given: nothing known to collide
            self.blocked = np.zeros(len(self.W), dtype=bool)
        self.N, self.T = self.ell.shape
        self.n_roadmap_edges = len(self.ends)
        if len(self.W) != self.n_roadmap_edges + len(self.src):
            raise ValueError(f"Expected {self.n_roadmap_edges + len(self.src)} cost rows, got {len(self.W)}")
        self.extra: dict[int, list[tuple[int, int]]] = {}  # temporary edges by source: [(dst, row)]
        for i, (a, b) in enumerate(zip(self.src.tolist(), self.dst.tolist())):
            self.extra.setdefault(a, []).append((b, self.n_roadmap_edges + i))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every directed spatial edge: ``(src, dst, row)`` arrays."""
        E = self.n_roadmap_edges
        rows = np.arange(E)
        a, b = self.ends[:, 0], self.ends[:, 1]
        return (np.concatenate([a, b, self.src]), np.concatenate([b, a, self.dst]),
                np.concatenate([rows, rows, E + np.arange(len(self.src))]))

    def row_of(self, a: int, b: int) -> int:
        """The cost row of the spatial edge ``a -> b``."""
        for w, r in self.extra.get(a, ()):
            if w == b:
                return r
        return int(self.graph.edges[a, b]["eid"])

    def successors(self, v: int) -> tuple[np.ndarray, np.ndarray]:
        """Spatial successors ``(N_v,)`` of ``v`` and their cost rows ``(N_v,)`` (blocked ones
        included): the roadmap's neighbours (``graph.adj[v]``, cached) and temporary edges."""
        hit = self.adjacency.get(v)
        if hit is None:
            if v in self.graph:
                adj = self.graph.adj[v]
                hit = (np.fromiter(adj, dtype=np.int64, count=len(adj)),
                       np.fromiter((d["eid"] for d in adj.values()), dtype=np.int64, count=len(adj)))
            else:
                hit = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
            self.adjacency[v] = hit
        extra = self.extra.get(v)
        if extra:
            return (np.concatenate([hit[0], [w for w, _ in extra]]).astype(np.int64),
                    np.concatenate([hit[1], [r for _, r in extra]]).astype(np.int64))
        return hit


def cost_to_go(g: SearchGraph, trans: np.ndarray, t_min: int = 0) -> np.ndarray:
    """``H (N, T)``: the least cost from ``(v, t)`` to the end of the task, for ``t >= t_min``
    (``H = 0`` before ``t_min``, where no search from ``t_min`` goes)."""
    N, T = g.N, g.T
    offsets = [k for k in range(1, trans.shape[1])]
    H = np.zeros((N, T))
    # reversed graph (edge a -> b becomes b -> a) plus a super source S = N with S -> v at term(v),
    # as one CSR matrix whose structure is the same at every step: only its entries are rewritten
    src, dst, row = g.arrays()
    rows = np.concatenate([dst, np.full(N, N)])
    cols = np.concatenate([src, np.arange(N)])
    order = np.argsort(rows, kind="stable")  # the spatial edges (rows < N) first, the super source last
    indptr = np.searchsorted(rows[order], np.arange(N + 2))
    n_sp = len(src)
    edge_rows = row[order[:n_sp]]  # (n_sp,) the cost row of each spatial entry
    blocked = np.flatnonzero(g.blocked[edge_rows])
    M = sp.csr_matrix((np.empty(n_sp + N), cols[order], indptr), shape=(N + 1, N + 1))
    data = M.data  # (n_sp + N,) written in place, step by step
    W_t = np.ascontiguousarray(g.W[:, t_min:].T)  # (T - t_min, E'): a step's costs side by side
    for t in range(T - 1, t_min - 1, -1):
        if t == T - 1:
            term = np.zeros(N)
            if g.goal is not None:
                term[:] = np.inf
                term[g.goal] = 0.0
        else:
            term = np.full(N, np.inf)
            for k in offsets:
                if t + k < T and np.isfinite(trans[t, k]):
                    term = np.minimum(term, trans[t, k] + g.ell[:, t + k] + H[:, t + k])
        w = W_t[t - t_min][edge_rows]
        finite = np.isfinite(w)
        if n_sp == 0 or not finite.any():  # staying in step t is forbidden: no motion
            H[:, t] = term
            continue
        w[~finite] = _BIG  # an edge of infinite cost is as good as blocked; the others stay open
        w[blocked] = _BIG
        data[:n_sp] = w
        data[n_sp:] = np.minimum(term, _BIG) + 1.0  # > 0, so that no entry reads as absent
        dist = dijkstra(M, directed=True, indices=N)[:N] - 1.0
        H[:, t] = np.where(dist >= _BIG * 0.5, np.inf, dist)
    return H


def astar(g: SearchGraph, trans: np.ndarray, H: np.ndarray, source: int, t0: int,
          max_expansions: int) -> tuple[list[tuple[int, int]], float, int]:
    """Least-cost path from ``(source, t0)`` to the last step (to ``(g.goal, T-1)`` with a goal).

    ``H`` must be a consistent lower bound of the cost-to-go (``cost_to_go`` of this graph or
    of one with more edges). Returns ``(path [(v, t), ...], cost, expanded)``; an empty path and
    inf when there is none. Raises ``SearchBudgetExceeded`` past ``max_expansions``.
    """
    T = g.T
    offsets = [k for k in range(1, trans.shape[1]) if np.isfinite(trans[:, k]).any()]
    trans_l = trans.tolist()
    blocked = g.blocked
    start = source * T + t0
    h0 = H[source, t0]
    if not math.isfinite(h0):
        return [], math.inf, 0
    best = np.full(g.N * T, np.inf)  # g-values by node id v * T + t
    best[start] = 0.0
    closed = np.zeros(g.N * T, dtype=bool)
    parent = {start: -1}
    heap = [(h0, 0.0, start)]
    expanded = 0
    while heap:
        _f, neg_g, node = heapq.heappop(heap)
        if closed[node]:
            continue
        closed[node] = True
        v, t = divmod(node, T)
        gv = -neg_g
        if t == T - 1 and (g.goal is None or v == g.goal):
            path = []
            while node != -1:
                path.append(divmod(node, T))
                node = parent[node]
            return path[::-1], gv, expanded
        expanded += 1
        if expanded > max_expansions:
            raise SearchBudgetExceeded(f"more than {max_expansions} nodes expanded")
        ws, rows = g.successors(v)
        if len(ws):  # spatial edges, all at once
            keep = ~blocked[rows]
            d = ws[keep]
            nxt = d * T + t
            ng = gv + g.W[rows[keep], t]
            h = H[d, t]
            better = (ng < best[nxt]) & np.isfinite(h) & ~closed[nxt]
            if better.any():
                nxt, ng, h = nxt[better], ng[better], h[better]
                best[nxt] = ng
                for n_, g_, f_ in zip(nxt.tolist(), ng.tolist(), (ng + h).tolist()):
                    parent[n_] = node
                    heapq.heappush(heap, (f_, -g_, n_))
        tr = trans_l[t]
        ev = g.ell[v]
        Hv = H[v]
        for k in offsets:  # time edges
            if t + k < T and tr[k] < math.inf:
                n_ = node + k
                g_ = gv + tr[k] + ev[t + k]
                if g_ < best[n_] and Hv[t + k] < math.inf and not closed[n_]:
                    best[n_] = g_
                    parent[n_] = node
                    heapq.heappush(heap, (g_ + Hv[t + k], -g_, n_))
    return [], math.inf, expanded
