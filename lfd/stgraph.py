"""The spatiotemporal roadmap (paper Sec. V-A, Fig. 3) as a lazily generated networkx DiGraph.

Nodes are ``(v, t)``: a roadmap vertex id ``v`` (ids < 0 are the temporary vertices of one plan:
``START`` = the robot's current configuration, ``GOAL`` = a given goal configuration) and a time
step ``t`` in ``0..T-1``. Edges (graph Cartesian product of the roadmap and the time-step graph):

* ``(v, t) -> (v, t + k)`` for each permitted offset ``k > 0`` (``SpatiotemporalCosts.time_cost``);
* ``(u, t) -> (w, t)`` for each collision-free roadmap edge ``u-w``
  (``SpatiotemporalCosts.spatial``);
* ``(START, t) -> (w, t)`` for the roadmap vertices ``w`` the robot's configuration is joined to,
  and ``(u, t) -> (GOAL, t)`` for those joined to the goal: START is a source and GOAL a sink
  (paths never come back to the robot's current configuration, nor leave the goal's);
* when no goal configuration is given, ``(v, T-1) -> SINK`` at cost 0, so that "any vertex at the
  last step" is one target node.

Materializing the product (n * T nodes, ~n * T * k edges) would cost seconds at n = 5,000, and
most of it is never reached. ``LazyProductGraph`` is a real ``nx.DiGraph`` whose successor mapping
``_adj`` builds a node's out-edges (with their costs) the first time the search reads them, which
is when networkx pops that node. ``nx.astar_path`` runs on it unchanged, with a callable weight that
returns the stored cost, and ``SpatiotemporalCosts.heuristic_fn`` (lfd.stheuristic, consistent)
as the heuristic; with ``heuristic=False`` it is Dijkstra's algorithm. The graph lives for one search only.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import networkx as nx

from lfd.stcost import SpatiotemporalCosts

__all__ = ["START", "GOAL", "SINK", "LazyProductGraph", "SearchResult", "SearchBudgetExceeded",
           "search"]

START = -1
GOAL = -2
SINK = (-3, -1)


class SearchBudgetExceeded(RuntimeError):
    """The search expanded more product nodes than allowed."""


class _Nodes(dict):
    """Membership of the implicit node set (``node in G`` for networkx's argument checks)."""

    def __init__(self, graph: "LazyProductGraph"):
        super().__init__()
        self._g = graph

    def __contains__(self, node) -> bool:
        return self._g.has_product_node(node)


class _Successors(dict):
    """``_adj[(v, t)]`` -> ``{(w, t'): cost}``, generated (and costed) on first access."""

    def __init__(self, graph: "LazyProductGraph"):
        super().__init__()
        self._g = graph

    def __missing__(self, node):
        succ = self._g.successors_with_costs(node)
        self[node] = succ
        return succ


class LazyProductGraph(nx.DiGraph):
    """Implicit spatiotemporal roadmap over ``costs`` (see module docstring).

    ``goal_vertex``: None (target ``SINK``: any vertex at step T-1) or a vertex id whose node at
    T-1 is the target. ``max_expansions`` bounds the number of nodes whose successors are built.
    ``succ_cache``: optional ``{v: {t: successors}}`` shared by the searches of one plan (Lazy
    PRM searches again after dropping colliding edges and re-expands mostly the same nodes); the
    caller must drop the entries of a vertex whose edges change (see ``ClosedLoopPlanner``).
    """

    def __init__(self, costs: SpatiotemporalCosts, goal_vertex: int | None = None,
                 max_expansions: int = 10 ** 7, succ_cache: dict | None = None):
        super().__init__()
        self.costs = costs
        self.T = costs.T
        self.goal_vertex = goal_vertex
        self.max_expansions = int(max_expansions)
        self.n_expanded = 0
        self._cache = succ_cache
        self._node = _Nodes(self)
        self._adj = self._succ = _Successors(self)

    @property
    def target(self):
        return SINK if self.goal_vertex is None else (self.goal_vertex, self.T - 1)

    def has_product_node(self, node) -> bool:
        if node == SINK:
            return self.goal_vertex is None
        try:
            v, t = node
        except (TypeError, ValueError):
            return False
        return bool(self.costs.has_vertex(v) and 0 <= t < self.T)

    def successors_with_costs(self, node) -> dict:
        if node == SINK:
            return {}
        self.n_expanded += 1
        if self.n_expanded > self.max_expansions:
            raise SearchBudgetExceeded(f"more than {self.max_expansions} nodes expanded")
        v, t = node
        if self._cache is not None:
            hit = self._cache.get(v, {}).get(t)
            if hit is not None:
                return hit
        c = self.costs
        nbrs, C = c.spatial(v)
        col = C[:, t].tolist() if len(nbrs) else []
        succ = {(w, t): x for w, x in zip(nbrs, col) if x < math.inf}
        if v >= 0 and c.joins_temporary(v):  # edges to the temporary vertices joined to v
            tn, tC = c.temporary_spatial(v)
            succ.update({(w, t): x for w, x in zip(tn, tC[:, t].tolist()) if x < math.inf})
        for k in c.time_offsets:
            if t + k < self.T:
                x = c.time_cost(v, t, k)
                if x < math.inf:
                    succ[(v, t + k)] = x
        if t == self.T - 1 and self.goal_vertex is None:
            succ[SINK] = 0.0
        if self._cache is not None:
            self._cache.setdefault(v, {})[t] = succ
        return succ


def _stored_cost(_u, _v, cost):
    return cost


@dataclass(frozen=True)
class SearchResult:
    """nodes: the product path ``[(v, t), ...]`` without SINK (empty when none); cost: its cost
    (inf when none); n_expanded: nodes whose successors were built; search_s: wall time."""
    nodes: tuple
    cost: float
    n_expanded: int
    search_s: float
    stats: dict = field(default_factory=dict)


def search(costs: SpatiotemporalCosts, start_vertex: int, t_start: int,
           goal_vertex: int | None = None, max_expansions: int = 10 ** 7,
           succ_cache: dict | None = None) -> SearchResult:
    """Minimum-cost path from ``(start_vertex, t_start)`` to step T-1 (or ``(goal_vertex, T-1)``).

    Call ``costs.prepare()`` first. Raises ``SearchBudgetExceeded`` past ``max_expansions`` and
    lets ``CostError`` from the step cost through; returns an empty result when no path exists.
    ``succ_cache``: see ``LazyProductGraph`` (valid for one goal and one ``prepare``).
    """
    if not 0 <= t_start < costs.T:
        raise ValueError(f"Expected t_start in [0, {costs.T - 1}], got {t_start}")
    G = LazyProductGraph(costs, goal_vertex, max_expansions, succ_cache)
    source = (start_vertex, t_start)
    if source not in G:
        raise ValueError(f"Expected start_vertex to be a vertex of the roadmap, got {start_vertex}")
    tic = time.perf_counter()
    h = costs.heuristic_fn()
    try:
        path = nx.astar_path(G, source, G.target, heuristic=h, weight=_stored_cost)
    except nx.NetworkXNoPath:
        return SearchResult((), math.inf, G.n_expanded, time.perf_counter() - tic)
    cost = math.fsum(G._adj[a][b] for a, b in zip(path[:-1], path[1:]))
    if path[-1] == SINK:
        path = path[:-1]
    return SearchResult(tuple(path), cost, G.n_expanded, time.perf_counter() - tic)
