"""Closed-loop planning on the spatiotemporal roadmap (paper Sec. V-B, last paragraph).

``ClosedLoopPlanner`` owns the lazy edge costs of one roadmap and re-plans from the robot's current
configuration and time step whenever asked. New sensed landmarks (``update_landmarks``) replace
the step cost and drop every landmark-dependent cache; the next ``plan`` recomputes only what its
search touches. Collision results of roadmap edges are kept (obstacles do not move).

The learned model reaches the planner through ``step_cost``, either

* a factory ``step_cost(a_hat) -> step_nll`` with ``step_nll(Q: (B, d)) -> (B, T)``; it may raise
  ``LookupError`` (e.g. ``KeyError``) when a task-relevant landmark is not in ``a_hat``; or
* an object with ``set_landmarks(a_hat)`` and ``step_nll(Q)`` (the same contract).

``a_hat`` is passed through untouched, except that an array-like with non-finite entries counts as
a missing landmark. ``plan`` never raises for run-time conditions: it returns a ``PlanResult``
whose ``status`` says what happened. Wrong shapes (programming errors) raise ``ValueError``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from lfd.roadmap import Roadmap
from lfd.stcost import CostError, CostSettings, SpatiotemporalCosts
from lfd.stgraph import GOAL, START, SearchBudgetExceeded, search

__all__ = ["PlannerSettings", "PlanResult", "ClosedLoopPlanner", "STATUSES"]

STATUSES = ("ok", "no_path", "start_in_collision", "goal_in_collision", "missing_landmark",
            "invalid_cost", "budget_exceeded", "unreachable")


@dataclass(frozen=True)
class PlannerSettings:
    """cost: CostSettings; max_expansions: search budget (product nodes), past which ``plan``
    returns 'budget_exceeded'; connect_k: neighbours tried for the start/goal configuration
    (None: k_PRM*(n + 1)); max_path_checks: searches at most per plan when edges are checked
    on the path (``cost.edge_checks == "path"``), past which ``plan`` returns 'budget_exceeded'."""
    cost: CostSettings = CostSettings()
    max_expansions: int = 500_000
    connect_k: int | None = None
    max_path_checks: int = 500

    def __post_init__(self):
        if self.max_expansions < 1:
            raise ValueError(f"Expected max_expansions >= 1, got {self.max_expansions}")
        if self.max_path_checks < 1:
            raise ValueError(f"Expected max_path_checks >= 1, got {self.max_path_checks}")
        if self.connect_k is not None and self.connect_k < 1:
            raise ValueError(f"Expected connect_k >= 1 or None, got {self.connect_k}")


@dataclass(frozen=True)
class PlanResult:
    """One plan.

    status: one of ``STATUSES``; configurations: (n, d) waypoints, the first is ``q_current``
    (empty unless 'ok'); time_steps: (n,) int task time step of each waypoint; vertices: (n,)
    roadmap ids (-1 = the start configuration, -2 = the goal configuration); cost: path cost (inf
    unless 'ok'); n_edges_evaluated: roadmap edges whose cost this plan computed; latency_s: wall
    time of ``plan``; stats: further counters (expanded nodes, step-cost rows, segment checks,
    ``cpu_s`` = process CPU time of the plan, a load-independent figure);
    message: a human-readable reason when not 'ok'.
    """
    status: str
    configurations: np.ndarray
    time_steps: np.ndarray
    vertices: np.ndarray
    cost: float
    n_edges_evaluated: int
    latency_s: float
    stats: dict = field(default_factory=dict)
    message: str = ""

    @property
    def ok(self) -> bool:
        return self.status == "ok"


class ClosedLoopPlanner:
    """Re-plans on ``roadmap`` for the current landmarks.

    Parameters
    ----------
    roadmap : Roadmap (may grow between plans with ``add_vertices``).
    step_cost : factory ``a_hat -> step_nll`` or model with ``set_landmarks``/``step_nll``.
    log_trans : (T, K) log-probabilities of the transitions ``offsets``.
    dt : sampling interval of the demonstrations (s).
    vmax : (d,) joint velocity limits (rad/s).
    offsets : permitted time-step offsets (must include 0 for roadmap edges to be usable).
    settings : PlannerSettings.
    """

    def __init__(self, roadmap: Roadmap, step_cost: Callable | Any, log_trans, dt: float, vmax,
                 offsets=(0, 1, 2), settings: PlannerSettings = PlannerSettings()):
        if not (callable(step_cost) or hasattr(step_cost, "set_landmarks")):
            raise ValueError("Expected step_cost to be a factory a_hat -> step_nll or an object "
                             f"with set_landmarks and step_nll, got {type(step_cost).__name__}")
        self.roadmap = roadmap
        self.step_cost = step_cost
        self.settings = settings
        self.costs = SpatiotemporalCosts(roadmap, log_trans, dt, vmax, offsets, settings.cost)
        self.T = self.costs.T
        self._landmark_error: str | None = "no landmarks yet: call update_landmarks"

    def update_landmarks(self, a_hat) -> None:
        """New sensed landmarks: invalidate the step costs (recomputed lazily by the next plan)."""
        self._landmark_error = None
        try:
            arr = np.asarray(a_hat, dtype=float)
            if not np.all(np.isfinite(arr)):
                self._landmark_error = "a_hat has non-finite entries (unsensed landmark)"
        except (TypeError, ValueError):
            pass  # not an array (e.g. a dict of poses): the model judges it
        if self._landmark_error is None:
            try:
                if hasattr(self.step_cost, "set_landmarks"):
                    self.step_cost.set_landmarks(a_hat)
                    fn = self.step_cost.step_nll
                else:
                    fn = self.step_cost(a_hat)
            except LookupError as e:
                self._landmark_error = f"missing landmark: {e}"
        if self._landmark_error is not None:
            self.costs.set_step_nll(None)
            return
        self.costs.set_step_nll(fn)

    def _search_free_path(self, t_start: int, to_goal: bool):
        """A* on the product graph; with edges checked on the path (Lazy PRM), check the unchecked
        roadmap edges of the path found, drop those that collide and search again, until the
        path is collision-free. Returns ``(path, cost, expanded, searches)``."""
        rm, lazy = self.roadmap, self.settings.cost.edge_checks == "path"
        expanded = 0
        succ = {}  # {v: {t: successors}}: the searches of this plan re-expand mostly the same nodes
        for searches in range(1, self.settings.max_path_checks + 1):
            res = search(self.costs, START, t_start, GOAL if to_goal else None, self.settings.max_expansions,
                         succ_cache=succ)
            expanded += res.n_expanded
            if not lazy or not res.nodes:
                return res.nodes, res.cost, expanded, searches
            collided = False
            for (a, ta), (b, tb) in zip(res.nodes[:-1], res.nodes[1:]):
                if a >= 0 and b >= 0 and a != b and not rm.edge_free(a, b):
                    self.costs.drop_edge(a, b)
                    succ.pop(a, None)
                    succ.pop(b, None)
                    collided = True
                    # an obstacle is near: settle every edge of both ends now, so the next
                    # search does not try their neighbours' colliding edges one by one
                    for v in (a, b):
                        before = list(rm.graph.adj[v])
                        kept = set(rm.free_neighbors(v))
                        for w in before:
                            if w not in kept:
                                self.costs.drop_edge(v, w)
                                succ.pop(w, None)
                        succ.pop(v, None)
            if not collided:
                return res.nodes, res.cost, expanded, searches
        raise SearchBudgetExceeded(f"no collision-free path after {self.settings.max_path_checks} "
                                   "searches (each dropped colliding edges)")

    def _result(self, status, tic, message="", path=(), cost=math.inf, stats=None) -> PlanResult:
        d = self.roadmap.d
        conf = np.array([self.costs.position(v) for v, _ in path]).reshape(len(path), d)
        return PlanResult(status=status, configurations=conf,
                          time_steps=np.array([t for _, t in path], dtype=int),
                          vertices=np.array([v for v, _ in path], dtype=int), cost=float(cost),
                          n_edges_evaluated=int((stats or {}).get("edges_evaluated", 0)),
                          latency_s=time.perf_counter() - tic, stats=dict(stats or {}),
                          message=message)

    def plan(self, q_current, t_current: int, q_goal=None) -> PlanResult:
        """Minimum-cost path from ``(q_current (d,), t_current)`` to step T-1.

        With ``q_goal (d,)`` the path must end at ``(q_goal, T-1)``; otherwise it ends at any
        vertex at step T-1. The returned waypoints start at ``q_current``.
        """
        tic, cpu0 = time.perf_counter(), time.process_time()
        d = self.roadmap.d
        q = np.asarray(q_current, dtype=float).reshape(-1)
        if q.shape != (d,) or not np.all(np.isfinite(q)):
            raise ValueError(f"Expected q_current finite with shape ({d},), got {q}")
        if int(t_current) != t_current or not 0 <= t_current < self.T:
            raise ValueError(f"Expected t_current an integer in [0, {self.T - 1}], got {t_current}")
        g = None if q_goal is None else np.asarray(q_goal, dtype=float).reshape(-1)
        if g is not None and (g.shape != (d,) or not np.all(np.isfinite(g))):
            raise ValueError(f"Expected q_goal finite with shape ({d},), got {g}")
        if self._landmark_error is not None:
            return self._result("missing_landmark", tic, self._landmark_error)
        rm = self.roadmap
        if rm.in_collision(q[None])[0]:
            return self._result("start_in_collision", tic, "q_current is in collision")
        if g is not None and rm.in_collision(g[None])[0]:
            return self._result("goal_in_collision", tic, "q_goal is in collision")
        seg0 = rm.counters["segment_checks"]
        c0 = dict(self.costs.counters)
        # the robot's configuration is a source, the goal a sink (see lfd.stgraph)
        temps, links = {START: q}, {START: rm.connect_point(q, self.settings.connect_k)}
        in_links = {}
        if g is not None:
            temps[GOAL] = g
            in_links[GOAL] = rm.connect_point(g, self.settings.connect_k)
            if rm.segment_free(q, g):  # a direct start-goal edge when it is free
                links[START].append(GOAL)
        self.costs.set_temporary(temps, links, in_links)
        status, message, path, cost, n_exp, searches = "ok", "", (), math.inf, 0, 0
        try:
            self.costs.prepare(int(t_current))
            path, cost, n_exp, searches = self._search_free_path(int(t_current), g is not None)
            if not path:
                status, message = "no_path", "no path to the last time step in the roadmap"
        except SearchBudgetExceeded as e:
            status, message = "budget_exceeded", str(e)
        except CostError as e:
            status, message = "invalid_cost", str(e)
        stats = {"edges_evaluated": self.costs.counters["edges"] - c0["edges"],
                 "points_evaluated": self.costs.counters["points"] - c0["points"],
                 "step_nll_calls": self.costs.counters["calls"] - c0["calls"],
                 "segment_checks": rm.counters["segment_checks"] - seg0,
                 "expanded": n_exp, "searches": searches if status == "ok" or path else 0,
                 "cpu_s": time.process_time() - cpu0}
        if status != "ok":
            path, cost = (), math.inf
        return self._result(status, tic, message, path, cost, stats)
