"""Closed-loop planning on the spatiotemporal roadmap (paper Sec. V-B, last paragraph).

``ClosedLoopPlanner`` plans from the robot's current configuration and time step whenever asked.
Edge knowledge lives in one ``lfd.planning.edgestore.EdgeStore``: new sensed landmarks
(``update_landmarks``) make every edge cost stale, and the next ``plan`` recomputes them in one
batch; an object that moved (``object_moved``) makes the collision state of the edges near
it unknown again. A plan:

1. costs every edge and vertex for the current landmarks, if stale (``EdgeStore.costs``; after
   the roadmap grew, only the new ones), and the
   edges joining the robot's configuration (and a goal configuration) to their ``connect_k``
   nearest vertices;
2. computes the exact cost-to-go of every product node with the edges not known to collide
   (``lfd.planning.stsearch.cost_to_go``) and runs A* with it from the robot's node;
3. checks the path's unchecked edges (Lazy PRM; all of them, then decides), marks the colliding
   ones (and every edge of an end vertex found in collision) and searches again with the same
   heuristic, a consistent lower bound, until the path is collision-free; when such a search
   expands many nodes, the heuristic is recomputed without the dropped edges first.

The returned path is the least-cost path of the roadmap among edges checked collision-free
(tests: ``tests/test_planner.py`` against networkx's Dijkstra on the fully evaluated product).
``plan`` never raises for run-time conditions: ``PlanResult.status`` says what happened; wrong
shapes (programming errors) raise ``ValueError``.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field

import numpy as np

from lfd.learning.tasks import is_real
from lfd.planning.edgestore import BLOCKED, FREE, UNKNOWN, EdgeStore
from lfd.planning.roadmap import Roadmap, k_prm_star
from lfd.planning.stepcost import CostError, StepCost
from lfd.planning.stsearch import SearchBudgetExceeded, SearchGraph, astar, cost_to_go, transition_table

__all__ = ["STATUSES", "ClosedLoopPlanner", "PlanResult", "PlannerSettings", "time_step"]

STATUSES = ("ok", "no_path", "start_in_collision", "goal_in_collision", "start_outside_limits",
            "goal_outside_limits", "missing_landmark", "invalid_cost", "budget_exceeded", "unreachable")
# A* expansions allowed with a heuristic computed before edges were dropped; past them the
# heuristic is recomputed (tens of ms) and the search runs again (measured: benchmarks/reaction.py)
STALE_EXPANSIONS = 300


def time_step(t, T: int) -> int:
    """``t`` as an ``int`` if it is a time step of a ``T``-step task (a whole number in ``[0, T)``,
    a whole float too), else a ``ValueError`` (``None``, NaN and ``True`` were TypeErrors or taken)."""
    if getattr(t, "ndim", None) == 0 and hasattr(t, "item"):
        t = t.item()  # a 0-d numpy or torch value (a torch bool stays refused)
    value = float(t) if is_real(t) else math.nan
    if not (math.isfinite(value) and value == int(value) and 0 <= value < T):
        raise ValueError(f"Expected t_current an integer in [0, {T - 1}], got {t!r}")
    return int(value)


@dataclass(frozen=True)
class PlannerSettings:
    """quad_dt: max time (s) between quadrature nodes along an edge (None: the model's dt, or
    ``lfd.planning.quadrature.MIN_QUAD_DT`` when the model's is shorter);
    max_expansions: A* budget (product nodes) past which ``plan`` returns 'budget_exceeded';
    connect_k: neighbours tried for the robot's (and a goal) configuration (None:
    k_PRM*(n + 1)); max_path_checks: searches per plan at most (each after dropping colliding
    edges of the previous path); sweep_margin: metres around the keypoints of an edge's motion
    within which a moved object makes the edge's collision state unknown."""
    quad_dt: float | None = None
    max_expansions: int = 500_000
    connect_k: int | None = None
    max_path_checks: int = 500
    sweep_margin: float = 0.15

    def __post_init__(self):
        if self.quad_dt is not None and not self.quad_dt > 0:
            raise ValueError(f"Expected quad_dt > 0, got {self.quad_dt}")
        if self.max_expansions < 1:
            raise ValueError(f"Expected max_expansions >= 1, got {self.max_expansions}")
        if self.max_path_checks < 1:
            raise ValueError(f"Expected max_path_checks >= 1, got {self.max_path_checks}")
        if self.connect_k is not None and self.connect_k < 1:
            raise ValueError(f"Expected connect_k >= 1 or None, got {self.connect_k}")
        if not self.sweep_margin >= 0:
            raise ValueError(f"Expected sweep_margin >= 0, got {self.sweep_margin}")


@dataclass(frozen=True)
class PlanResult:
    """One plan.

    status: one of ``STATUSES``; configurations: (n, d) waypoints, the first is ``q_current``
    (empty unless 'ok'); time_steps: (n,) int task time step of each waypoint; vertices: (n,)
    roadmap ids (-1 = the start configuration, -2 = the goal configuration); cost: path cost (inf
    unless 'ok'); n_edges_evaluated: roadmap edges whose cost this plan computed; latency_s: wall
    time of ``plan``; stats: its parts, in seconds (``cost_s`` edge costs, ``heuristic_s``
    cost-to-go, ``search_s`` A*, ``collision_s`` checks of the path's edges) and counts
    (``searches``, ``heuristics``, ``expanded``, ``segment_checks``, ``blocked``), ``cpu_s``
    (process CPU time, a load-independent figure); message: a reason when not 'ok'.
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


class _Temporary:
    """The per-plan vertices (robot configuration, optional goal) and their one-way edges."""

    def __init__(self, n: int):
        self.n = n
        self.q: list[np.ndarray] = []
        self.ell: list[np.ndarray] = []
        self.src: list[int] = []
        self.dst: list[int] = []
        self.W: list[np.ndarray] = []
        self.state: list[int] = []

    def add_vertex(self, q: np.ndarray, ell: np.ndarray) -> int:
        self.q.append(q)
        self.ell.append(ell)
        return self.n + len(self.q) - 1

    def add_edges(self, src, dst, W) -> None:
        self.src += list(np.broadcast_to(src, (len(W),)))
        self.dst += list(np.broadcast_to(dst, (len(W),)))
        self.W.append(W)
        self.state += [UNKNOWN] * len(W)


class ClosedLoopPlanner:
    """Re-plans on ``roadmap`` for the current landmarks.

    Parameters
    ----------
    roadmap : Roadmap (may grow between plans).
    step_cost : ``lfd.planning.stepcost.StepCost`` (e.g. ``ModelStepCost(model)``).
    trans_cost : (T, K) costs of the transitions ``offsets`` in the step cost's units (inf =
        not permitted), e.g. ``TaskModel.trans_cost``.
    dt : sampling interval of the demonstrations (s); vmax : (d,) joint velocity limits.
    offsets : permitted time-step offsets (must include 0 for roadmap edges to be usable).
    keypoint_fn : optional ``Q (N, d) -> (N, K, 3)`` points the robot sweeps (for
        ``object_moved``; without it a moved object makes every edge stale).
    settings : PlannerSettings.
    """

    def __init__(self, roadmap: Roadmap, step_cost: StepCost, trans_cost, dt: float, vmax,
                 offsets=(0, 1, 2), settings: PlannerSettings = PlannerSettings(), keypoint_fn=None):
        tc = np.asarray(trans_cost, dtype=float)
        offsets = tuple(int(k) for k in offsets)
        if tc.ndim != 2 or tc.shape[1] != len(offsets) or len(tc) < 1:
            raise ValueError(f"Expected trans_cost with shape (T, {len(offsets)}), got {tc.shape}")
        if np.any(tc < -1e-9):
            raise ValueError(f"Expected trans_cost >= 0 (negative log-probabilities), got a minimum of {tc.min()}")
        if any(k < 0 for k in offsets) or len(set(offsets)) != len(offsets):
            raise ValueError(f"Expected distinct non-negative offsets, got {offsets}")
        if getattr(step_cost, "T", len(tc)) != len(tc):
            raise ValueError(f"step_cost has {step_cost.T} time steps, trans_cost {len(tc)}")
        self.roadmap, self.settings = roadmap, settings
        self.trans = transition_table(tc, offsets)  # (T, kmax + 1)
        self.T = len(tc)
        stay = self.trans[:, 0] if 0 in offsets else np.full(self.T, np.inf)
        self.edges = EdgeStore(roadmap, step_cost, stay, dt, vmax, settings.quad_dt, keypoint_fn,
                               settings.sweep_margin)
        self._landmark_error: str | None = "no landmarks yet: call update_landmarks"
        self._adjacency: dict = {}  # the roadmap's adjacency as arrays, read by A* (lfd.planning.stsearch)
        self._adjacency_edges = -1

    # ------------------------------------------------------------------ what changed
    def update_landmarks(self, landmarks) -> None:
        """New sensed landmarks: every edge cost is stale (recomputed by the next plan). An
        array-like with non-finite entries counts as a missing landmark."""
        self._landmark_error = None
        try:
            if not np.all(np.isfinite(np.asarray(landmarks, dtype=float))):
                self._landmark_error = "the landmarks have non-finite entries (not sensed)"
        except (TypeError, ValueError):
            pass  # not an array (e.g. a dict of poses): the step cost judges it
        self.edges.invalidate(landmarks=landmarks)

    def object_moved(self, old_centre, new_centre, radius: float, name: str | None = None) -> int:
        """An object of about ``radius`` moved from ``old_centre (3,)`` to ``new_centre (3,)``
        (either may be None: it appeared or left): blocked edges near its old place may be free
        now, free edges near its new place are checked again when a path uses them
        (``EdgeStore.invalidate``). ``name``: the object's, exactly as the collision callables
        name what they hit (``Roadmap.hits``): then the blocked edges seen hitting something else
        stay blocked (sound as long as every object that moves is reported). Returns how many
        edges were reset at once."""
        return self.edges.invalidate(vacated=None if old_centre is None else (old_centre, radius, name),
                                     occupied=None if new_centre is None else (new_centre, radius))

    # ------------------------------------------------------------------ planning
    def _result(self, status, tic, message="", path=(), temps=None, cost=math.inf, stats=None) -> PlanResult:
        d, V = self.roadmap.d, self.roadmap.vertices
        n = self.roadmap.n
        conf = np.array([V[v] if v < n else temps.q[v - n] for v, _ in path]).reshape(len(path), d)
        ids = np.array([v if v < n else -1 - (v - n) for v, _ in path], dtype=int)
        return PlanResult(status=status, configurations=conf,
                          time_steps=np.array([t for _, t in path], dtype=int), vertices=ids,
                          cost=float(cost), n_edges_evaluated=int((stats or {}).get("edges_evaluated", 0)),
                          latency_s=time.perf_counter() - tic, stats=dict(stats or {}), message=message)

    def _check_q(self, q, name):
        q = np.array(q, dtype=float).reshape(-1)  # a copy: the caller's array is never written
        if q.shape != (self.roadmap.d,) or not np.all(np.isfinite(q)):
            raise ValueError(f"Expected {name} finite with shape ({self.roadmap.d},), got {q}")
        return q

    def plan(self, q_current, t_current: int, q_goal=None) -> PlanResult:
        """Minimum-cost path from ``(q_current (d,), t_current)`` to step T-1.

        With ``q_goal (d,)`` the path must end at ``(q_goal, T-1)``; otherwise it ends at any
        vertex at step T-1. The returned waypoints start at ``q_current``.
        """
        tic, cpu0 = time.perf_counter(), time.process_time()
        q = self._check_q(q_current, "q_current")
        t_current = time_step(t_current, self.T)
        g = None if q_goal is None else self._check_q(q_goal, "q_goal")
        if self._landmark_error is not None:
            return self._result("missing_landmark", tic, self._landmark_error)
        rm, E = self.roadmap, self.edges
        if rm.in_collision(q[None])[0]:
            return self._result("start_in_collision", tic, "q_current is in collision")
        if g is not None and rm.in_collision(g[None])[0]:
            return self._result("goal_in_collision", tic, "q_goal is in collision")
        stats = {"cost_s": 0.0, "heuristic_s": 0.0, "search_s": 0.0, "collision_s": 0.0, "searches": 0,
                 "heuristics": 0, "expanded": 0, "segment_checks": 0, "blocked": 0, "edges_evaluated": 0}
        t0 = time.perf_counter()
        try:
            E.sync()
            costed = E.counters["costed_edges"]
            ell, W = E.costs()
            stats["edges_evaluated"] = E.counters["costed_edges"] - costed
            temps = self._temporaries(q, g)
        except LookupError as e:
            return self._result("missing_landmark", tic, f"missing landmark: {e}")
        except CostError as e:
            return self._result("invalid_cost", tic, str(e))
        stats["cost_s"] = time.perf_counter() - t0
        status, message, cost = "ok", "", math.inf
        path: list = []
        try:
            path, cost = self._search(temps, int(t_current), g is not None, ell, W, stats)
            if not path:
                status, message = "no_path", "no collision-free path to the last time step in the roadmap"
        except SearchBudgetExceeded as e:
            status, message = "budget_exceeded", str(e)
        stats["cpu_s"] = time.process_time() - cpu0
        if status != "ok":
            path, cost = [], math.inf
        return self._result(status, tic, message, path, temps, cost, stats)

    def _temporaries(self, q: np.ndarray, g: np.ndarray | None) -> _Temporary:
        """The robot's configuration (a source) and the goal (a sink), joined to their nearest."""
        rm, E = self.roadmap, self.edges
        k = self.settings.connect_k or k_prm_star(rm.n + 1, rm.d)
        temps = _Temporary(rm.n)
        ids = rm.nearest(q, k)
        ell_q, Wq = E.segment_costs(q, rm.vertices[ids])
        s = temps.add_vertex(q, ell_q)
        temps.add_edges(s, ids, Wq)
        if g is not None:
            ids_g = rm.nearest(g, k)
            ell_g, Wg = E.segment_costs(g, rm.vertices[ids_g])  # symmetric: the cost into g
            goal = temps.add_vertex(g, ell_g)
            temps.add_edges(ids_g, goal, Wg)
            _, Wsg = E.segment_costs(q, g[None])
            temps.add_edges(s, goal, Wsg)
        return temps

    def _graph(self, temps: _Temporary, ell: np.ndarray, W: np.ndarray, goal: bool) -> SearchGraph:
        """The plan's search graph: the roadmap's edges (both ways) and the temporary edges; rows
        known to collide are marked in ``blocked`` (kept current by ``_check_path``)."""
        E = self.edges
        if self._adjacency_edges != len(E.ends):  # the roadmap grew: its adjacency changed
            self._adjacency, self._adjacency_edges = {}, len(E.ends)
        return SearchGraph(graph=self.roadmap.graph, ends=E.ends, adjacency=self._adjacency,
                           src=np.array(temps.src, dtype=np.int64), dst=np.array(temps.dst, dtype=np.int64),
                           W=np.concatenate([W, *temps.W]), ell=np.concatenate([ell, np.stack(temps.ell)]),
                           goal=temps.n + 1 if goal else None,
                           blocked=np.concatenate([E.state == BLOCKED, np.zeros(len(temps.src), dtype=bool)]))

    def _search(self, temps: _Temporary, t0: int, goal: bool, ell, W, stats) -> tuple[list, float]:
        """A* with the exact cost-to-go, then Lazy PRM checks of the path, until it is free."""
        H = None
        source = temps.n
        G = self._graph(temps, ell, W, goal)
        for _ in range(self.settings.max_path_checks):
            budget = self.settings.max_expansions
            if H is not None:
                budget = min(budget, STALE_EXPANSIONS)
            for attempt in range(2):
                if H is None:
                    tic = time.perf_counter()
                    H = cost_to_go(G, self.trans, t0)
                    stats["heuristic_s"] += time.perf_counter() - tic
                    stats["heuristics"] += 1
                tic = time.perf_counter()
                try:
                    path, cost, n_exp = astar(G, self.trans, H, source, t0, budget)
                    stats["expanded"] += n_exp
                    break
                except SearchBudgetExceeded:
                    stats["expanded"] += budget
                    if budget >= self.settings.max_expansions:
                        raise
                    H, budget = None, self.settings.max_expansions  # recompute, search again
                finally:
                    stats["search_s"] += time.perf_counter() - tic
                    stats["searches"] += 1
            if not path:
                return [], math.inf
            tic = time.perf_counter()
            blocked = self._check_path(G, temps, path, stats)
            stats["collision_s"] += time.perf_counter() - tic
            if not blocked:
                return path, cost
        raise SearchBudgetExceeded(f"no collision-free path after {self.settings.max_path_checks} "
                                   "searches (each dropped colliding edges)")

    def _check_path(self, G: SearchGraph, temps: _Temporary, path, stats) -> bool:
        """Check the unchecked edges of ``path`` (all of them); True when one collided."""
        rm, E = self.roadmap, self.edges
        n_rm = len(E.ends)
        rows = []
        for (a, ta), (b, tb) in itertools.pairwise(path):
            if a != b:
                rows.append(G.row_of(a, b))
        hit = False
        checks0, blocked0 = E.counters["segment_checks"], E.counters["blocked"]
        # a batch of cheap point checks first: every way out of the path's vertices that has not
        # been screened since a nearby object moved (none far from moved objects)
        verts = {v for v, _ in path if v < rm.n}
        E.screen([e for _, _, e in rm.graph.edges(verts, data="eid")])
        for r in rows:
            if r < n_rm:
                if not E.check([r])[0]:
                    hit = True
                    for v in E.ends[r]:
                        incident = E.incident(v)
                        what = rm.hits(rm.vertices[v][None])[0]
                        if what:  # e.g. an object moved onto it
                            E.set_blocked(incident, at_vertex=int(v), what=what)
                        else:  # an obstacle is near: a cheap look at the other ways out of v
                            E.screen(incident)
            else:
                i = r - n_rm
                if temps.state[i] == UNKNOWN:
                    a, b = temps.src[i], temps.dst[i]
                    qa = temps.q[a - temps.n] if a >= temps.n else rm.vertices[a]
                    qb = temps.q[b - temps.n] if b >= temps.n else rm.vertices[b]
                    stats["segment_checks"] += 1
                    temps.state[i] = BLOCKED if rm.segment_collides(qa, qb) else FREE
                    if temps.state[i] == BLOCKED:
                        hit = True
                        stats["blocked"] += 1
        stats["segment_checks"] += E.counters["segment_checks"] - checks0
        stats["blocked"] += E.counters["blocked"] - blocked0
        G.blocked[:n_rm] = E.state == BLOCKED
        G.blocked[n_rm:] = np.array(temps.state) == BLOCKED
        return hit
