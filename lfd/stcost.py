"""Lazy, cached edge costs of the spatiotemporal roadmap (paper Sec. V-B).

Inputs: the learned model's per-step cost ``step_nll(Q: (B, d)) -> (B, T)`` = L(q | zeta, eta_t,
a_hat) for the current landmarks, the transition table ``log_trans: (T, K)`` over ``offsets``
(``log_trans[t, i]`` = log p(t + offsets[i] | t)), the demonstrations' sampling interval ``dt`` and
the joint velocity limits ``vmax: (d,)``.

Costs (``ell`` is the shifted step cost, below):

* time edge ``(v, t) -> (v, t + k)``, k in offsets, k > 0: one sampling interval at ``q_v``:
  ``-log_trans[t, k] + ell(q_v, t + k)``;
* roadmap edge ``(u, t) -> (w, t)``: the robot moves ``q_u -> q_w`` at its velocity limits, taking
  ``tau = max_j |q_w - q_u|_j / vmax_j`` seconds = ``tau / dt`` sampling intervals, each of which
  is a self-transition at step ``t``. The cost is the line integral over time
  ``(1/dt) * int_0^tau [ -log p(t | t) + ell(q(s), t) ] ds``
  ``= (tau/dt) * ( -log p(t|t) + mean_s ell(q(s), t) )``, with the mean over the segment taken by
  the trapezoid rule on ``m + 1`` equally spaced points, ``m = max(1, ceil(tau / quad_dt))``
  (``quad_dt`` defaults to ``dt``; the error is O(1/m^2) for smooth costs). Edges are evaluated
  for all T steps at once, so one ``step_nll`` call on the interior points of all edges of a
  vertex serves every time layer. Roadmap edges need ``offsets`` to contain 0.

Non-negative costs. A Gaussian negative log-likelihood is negative where the density exceeds 1,
and Dijkstra/A* need non-negative edge costs. We use ``ell(q, t) = max(L(q|t) - s, 0)`` with the
constant ``s = min(0, floor)``, where ``floor`` is ``CostSettings.nll_floor`` when given (a true
lower bound, e.g. ``min_t 1/2 log det(2 pi Sigma_t)`` in nll units), otherwise the minimum of L
over every roadmap vertex and step (one batched call per landmark update). Subtracting ``s`` from
every sampling interval adds ``|s|`` per interval: the planner minimizes
``sum nll + |s| * (path duration / dt)``, i.e. the paper's cost plus a time penalty; for a fixed
path duration the optimum is unchanged. The clamp at 0 is active only where L is below the floor,
which never happens when the floor is a true bound (and, when estimated, only between vertices).

Per-step floor. With ``nll_floor`` given per step (``lfd.task_planner`` passes the model's
``s log|Sigma_t|``, its default), ``ell`` is the Mahalanobis term alone and there is no time
penalty beyond ``-log p(t|t)``. Why: the single shift charges ``|s|`` for every sampling interval
spent moving, while a time edge charges one interval for a whole time step; at the pour
demonstrations' 50 Hz (``|s|`` ~ 67 per 0.02 s) moving 0.1 s cost more than holding a worse
posture for several steps, and plans held one 85-95 degree posture through the whole pour where
the model's steps asked for 100-105 degrees (the pitcher needs ~100 to empty).

Dwell. A time edge stands for one sampling interval, so a path that holds a configuration
through a step pays that step's cost once, while a roadmap edge pays for every interval it
takes; the paper's most probable path therefore runs through the task's steps as fast as it
can. An executor that holds each step for the demonstrations' time in it (``sim.execute``,
before ``lfd.timing.step_clock``: ``dt / (1 - p(t|t))``) then spends most of the task at
configurations the cost barely weighed: on the 48-step pour, plans held one 94-degree posture through every
pouring step, the cheapest to reach, where the steps asked for 100-106 degrees. With
``dwell="expected"`` a time edge leaving step t at ``q`` also charges the step's expected
further stay, ``D_t = p/(1-p)`` intervals (``p = p(t|t)``), each at ``-log p(t|t) + ell(q, t)``:
the expected negative log-likelihood of the executed stay, so the cost weighs each step by the
time the robot will spend in it. A step that a time edge skips (t -> t + 2) is charged as if
held at the same configuration (its ``1 + D`` intervals): without that, skipping would be the
cheap way past a step the demonstrations stayed in long (``-log p`` of a skip is a few units,
a stay tens of intervals), whatever the configuration. Motion inside a step is charged on top
of the stay, not instead of part of it: a slight over-charge for moving, which keeps costs per
edge. Not the default: on the 48-step pour it fixed partial pours but its plans move between
pouring postures and some spill beside the bowl (measurements: README, *Results*).
With ``dwell="occupancy"``, ``D_t = occ_t / dt - 1`` intervals (at least 0), where
``occ_t = clock[t + 1] - clock[t]`` is the learned chain's mean time in step t per run, skipped
runs included (``lfd.timing.step_clock``): the time ``sim.execute`` aims to spend in that step
(less motion, at least one interval per transition). Unlike the expected stay, a step that
most demonstrations passed through at once and one stayed in long weighs only its share of the
demonstrated time. The weights themselves: ``lfd.timing.dwell_intervals``.

A* heuristic: ``lfd.stheuristic``, the cost-to-go of a relaxed problem (roadmap edges charged
only their self-transition part), a consistent lower bound computed for all vertices at once.

Caches: raw vertex costs ``(n, T)`` keyed by vertex id, per-vertex edge cost tables, both dropped
by ``set_step_nll`` (new landmarks); temporary vertices (the robot's current configuration, a
goal) are ids < 0, re-set for every plan and never accumulate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from lfd.roadmap import Roadmap
from lfd.stheuristic import dwell_charge, relaxed_cost_to_go, source_bound
from lfd.timing import DWELLS, dwell_intervals

__all__ = ["CostSettings", "CostError", "SpatiotemporalCosts", "EDGE_CHECKS", "DWELLS"]

EDGE_CHECKS = ("path", "expand")


class CostError(ValueError):
    """The step cost returned something unusable (wrong shape, NaN, +inf everywhere...)."""


@dataclass(frozen=True)
class CostSettings:
    """quad_dt: max time (s) between quadrature nodes along an edge (None: the model's dt);
    nll_floor: known lower bound on step_nll: one number (the shift is ``min(0, floor)``), or
    one per time step ``(T,)`` (the shift is that bound itself, per step: with the model's
    ``s log|Sigma_t|`` the shifted cost is exactly the Mahalanobis term), or None (estimated
    from all roadmap vertices, one number);
    heuristic: compute the A* heuristic (needs every vertex's cost, one batched call);
    heuristic_sweeps: move-first relaxations of the heuristic (lfd.stheuristic), 0 = time only;
    max_batch: rows per step_nll call; dtype: of the tensors passed to step_nll;
    edge_checks: when roadmap edges are collision-checked: "expand" (every edge of a vertex the
    search expands, before costing it) or "path" (Lazy PRM: the search treats unchecked edges
    as free and the planner checks only the edges of the path it returns, dropping colliding
    ones and searching again until the path is free; far fewer checks);
    dwell: what a time edge charges for the step it leaves, see *Dwell* in the module docstring:
    "interval" (the paper's: one sampling interval, charged at the step it enters), "expected"
    (also the step's expected further stay ``p/(1-p)`` intervals, ``p = p(t|t)``, at the
    configuration it is left from) or "occupancy" (also the rest of the step's mean time per
    demonstration, ``lfd.timing.step_clock``: the executor's pace);
    trans_scale: ``log_trans`` is this multiple of the log transition probabilities
    (``lfd.task_planner`` passes ``2 log p``, Eq. 3 units, and sets 2): the expected dwell reads
    ``p = exp(log_trans / trans_scale)``."""
    quad_dt: float | None = None
    nll_floor: float | tuple[float, ...] | None = None
    heuristic: bool = True
    heuristic_sweeps: int = 3
    max_batch: int = 16384
    dtype: torch.dtype = torch.float64
    edge_checks: str = "path"
    dwell: str = "interval"
    trans_scale: float = 1.0

    def __post_init__(self):
        if self.quad_dt is not None and not self.quad_dt > 0:
            raise ValueError(f"Expected quad_dt > 0, got {self.quad_dt}")
        if self.heuristic_sweeps < 0:
            raise ValueError(f"Expected heuristic_sweeps >= 0, got {self.heuristic_sweeps}")
        if self.max_batch < 1:
            raise ValueError(f"Expected max_batch >= 1, got {self.max_batch}")
        if self.edge_checks not in EDGE_CHECKS:
            raise ValueError(f"Expected edge_checks in {EDGE_CHECKS}, got {self.edge_checks!r}")
        if self.dwell not in DWELLS:
            raise ValueError(f"Expected dwell in {DWELLS}, got {self.dwell!r}")
        if not self.trans_scale > 0:
            raise ValueError(f"Expected trans_scale > 0, got {self.trans_scale}")


class SpatiotemporalCosts:
    """Edge costs of the spatiotemporal roadmap over ``roadmap``, evaluated lazily and cached.

    Parameters
    ----------
    roadmap : Roadmap (its lazy edge checks are triggered by ``spatial``).
    log_trans : (T, K) log-probabilities of the transitions ``offsets``; -inf = not permitted.
    dt : sampling interval (s) of the demonstrations.
    vmax : (d,) joint velocity limits (rad/s), all > 0.
    offsets : (K,) non-negative time-step offsets, e.g. (0, 1, 2).
    """

    def __init__(self, roadmap: Roadmap, log_trans, dt: float, vmax, offsets=(0, 1, 2),
                 settings: CostSettings = CostSettings()):
        lt = np.asarray(log_trans, dtype=float)
        offsets = tuple(int(k) for k in offsets)
        if lt.ndim != 2 or lt.shape[1] != len(offsets) or lt.shape[0] < 1:
            raise ValueError(f"Expected log_trans with shape (T, {len(offsets)}), got {lt.shape}")
        if np.any(lt > 1e-9):
            raise ValueError("Expected log_trans <= 0 (log-probabilities), got a maximum of "
                             f"{lt.max()}")
        if any(k < 0 for k in offsets) or len(set(offsets)) != len(offsets):
            raise ValueError(f"Expected distinct non-negative offsets, got {offsets}")
        if not dt > 0:
            raise ValueError(f"Expected dt > 0, got {dt}")
        vmax = np.asarray(vmax, dtype=float).reshape(-1)
        if vmax.shape != (roadmap.d,) or not np.all(vmax > 0):
            raise ValueError(f"Expected vmax with shape ({roadmap.d},) and > 0, got {vmax}")
        self.roadmap, self.dt, self.vmax, self.settings = roadmap, float(dt), vmax, settings
        self.T = lt.shape[0]
        floor = settings.nll_floor
        if floor is not None and (np.ndim(floor) > 1 or (np.ndim(floor) == 1 and len(floor) != self.T)
                                  or not np.isfinite(np.asarray(floor, dtype=float)).all()):
            raise ValueError(f"Expected nll_floor to be one finite number or {self.T} (one per time step), "
                             f"got {floor!r}")
        # the shift a known floor gives, once: the bound itself per step, min(0, floor) for one number
        self._known_shift = None if floor is None else (
            np.asarray(floor, dtype=float) if np.ndim(floor) == 1 else np.asarray(min(0.0, float(floor))))
        self.quad_dt = float(settings.quad_dt or dt)
        # trans[t, k] = -log p(t + k | t) for k in 0..max(offsets), inf where not permitted
        trans = np.full((self.T, max(offsets) + 1), np.inf)
        for i, k in enumerate(offsets):
            trans[:, k] = -lt[:, i]
        trans[~np.isfinite(trans)] = np.inf
        for k in range(trans.shape[1]):
            trans[max(self.T - k, 0):, k] = np.inf  # t + k beyond the last step
        self.trans = trans  # trans[:, 0] = -log p(t | t): the cost rate of roadmap edges
        # dwell[t]: further sampling intervals charged when step t is left by a time edge, each at
        # -log p(t|t) (stay_cost[t] in all) plus the step cost of the configuration it is left from
        order = np.argsort(offsets)
        self.dwell = dwell_intervals(settings.dwell, lt[:, order] / settings.trans_scale,  # (T,)
                                     sorted(offsets))
        stay = np.where(np.isfinite(trans[:, 0]), trans[:, 0], 0.0)
        self.stay_cost = np.where(self.dwell > 0, self.dwell * stay, 0.0)  # (T,)
        # what the heuristic needs to charge the same (None: one interval per time edge)
        self._dwell_terms = (self.dwell, self.stay_cost) if settings.dwell != "interval" else None
        self.time_offsets = tuple(k for k in offsets if k > 0)
        self._step_nll: Callable | None = None
        self._temp: dict[int, np.ndarray] = {}
        self._links: dict[int, list[int]] = {}  # temp id -> vertices it has edges to
        self._in: dict[int, list[int]] = {}  # temp id -> roadmap ids with edges into it
        self._back: dict[int, list[int]] = {}  # roadmap id -> temp ids it has edges to
        self._relaxed: tuple | None = None  # (n, src, dst, tau) of the roadmap, for stheuristic
        self._adjc: dict[int, tuple] = {}  # v -> (free nbrs, as array, eids): landmark-free
        self._graph_size = roadmap.graph.number_of_nodes()
        self._ecost = np.empty((roadmap.n_edge_ids, self.T))
        self._ehave = np.zeros(roadmap.n_edge_ids, dtype=bool)
        self._epoch = 0
        self.counters = {"edges": 0, "points": 0, "calls": 0}
        self._reset()

    # ------------------------------------------------------------------ invalidation
    def _reset(self) -> None:
        self._vraw = np.full((self.roadmap.n, self.T), np.nan)  # raw L(q_v | t), by vertex id
        self._tempraw: dict[int, np.ndarray] = {}
        self._shift: np.ndarray | None = None  # () or (T,)
        self._G: np.ndarray | None = None  # heuristic rows: roadmap, then temps with in-edges
        self._Gkey, self._Gtmin = None, 0
        self._Grow: dict[int, int] = {}  # temp id -> row of _G
        self._Gsrc: dict[int, np.ndarray] = {}  # source-only temp id -> (T,) bound
        self._out: dict[int, tuple[list[int], np.ndarray]] = {}  # v -> (nbrs, (deg, T) costs)
        self._ehave[:] = False  # roadmap edge costs, by edge id: _ecost[eid] valid iff _ehave
        self._tout: dict[int, tuple[list[int], np.ndarray]] = {}  # per plan, see set_temporary
        self._tedge: dict[tuple[int, int], np.ndarray] = {}  # per plan, edges with a temp vertex

    def set_step_nll(self, step_nll: Callable) -> None:
        """New landmarks: use ``step_nll`` from now on and drop every landmark-dependent cache."""
        self._step_nll = step_nll
        self._epoch += 1
        self._reset()

    def set_temporary(self, temps: dict[int, np.ndarray], links: dict[int, list[int]],
                      in_links: dict[int, list[int]] | None = None) -> None:
        """Temporary vertices for one plan: ``temps[id < 0] = q (d,)`` with directed edges to the
        vertices ``links[id]`` and from the roadmap vertices ``in_links[id]`` (all collision-checked
        by the caller). The robot's configuration is a source (no in-links), a goal a sink (no
        links). Replaces the previous temporary vertices and their cached edges."""
        for i in [i for i in self._out if i < 0]:
            del self._out[i]
        self._tout, self._tedge = {}, {}
        d = self.roadmap.d
        self._temp = {i: np.asarray(q, dtype=float).reshape(d) for i, q in temps.items()}
        self._links = {i: list(links.get(i, [])) for i in self._temp}
        self._in = {i: list((in_links or {}).get(i, [])) for i in self._temp}
        self._back = {}
        for i, ws in self._in.items():
            for w in ws:
                self._back.setdefault(w, []).append(i)
        self._tempraw = {}

    # ------------------------------------------------------------------ evaluation
    def _eval(self, Q: np.ndarray) -> np.ndarray:
        """Raw step costs ``(B, T)`` of ``Q: (B, d)``, in chunks of ``max_batch``."""
        if self._step_nll is None:
            raise CostError("no step cost set: call set_step_nll first")
        out = np.empty((len(Q), self.T))
        for a in range(0, len(Q), self.settings.max_batch):
            chunk = torch.tensor(Q[a:a + self.settings.max_batch], dtype=self.settings.dtype)
            try:
                with torch.no_grad():
                    L = self._step_nll(chunk)
            except Exception as e:  # the model's failure becomes the plan's status, not a crash
                raise CostError(f"step_nll failed: {e!r}") from e
            L = np.asarray(L.detach().cpu() if hasattr(L, "detach") else L, dtype=float)
            if L.shape != (len(chunk), self.T):
                raise CostError(f"Expected step_nll to return shape ({len(chunk)}, {self.T}), "
                                f"got {L.shape}")
            if np.isnan(L).any():
                raise CostError("step_nll returned NaN")
            out[a:a + len(chunk)] = L
            self.counters["calls"] += 1
        self.counters["points"] += len(Q)
        return out

    def position(self, v: int) -> np.ndarray:
        """(d,) configuration of vertex ``v`` (roadmap id, or a temporary id < 0)."""
        return self._temp[v] if v < 0 else self.roadmap._buf[v]

    def _ensure_vertices(self, ids) -> None:
        """Fill the raw cost of roadmap vertices ``ids`` that are not cached yet."""
        if self._vraw.shape[0] < self.roadmap.n:  # the roadmap grew: extend, keep old rows
            grow = np.full((self.roadmap.n - self._vraw.shape[0], self.T), np.nan)
            self._vraw = np.concatenate([self._vraw, grow], axis=0)
        ids = np.asarray(ids, dtype=int)
        miss = ids[np.isnan(self._vraw[ids, 0])]
        if len(miss):
            miss = np.unique(miss)
            self._vraw[miss] = self._eval(self.roadmap._buf[miss])

    def _raw(self, v: int) -> np.ndarray:
        """(T,) raw step cost of vertex v (roadmap or temporary)."""
        if v < 0:
            if v not in self._tempraw:
                self._tempraw[v] = self._eval(self._temp[v][None])[0]
            return self._tempraw[v]
        if v >= self._vraw.shape[0] or np.isnan(self._vraw[v, 0]):
            self._ensure_vertices([v])
        return self._vraw[v]

    def prepare(self, t_start: int = 0) -> None:
        """Per plan: vertex costs and shift (and the heuristic from step ``t_start`` on) for the
        current landmarks."""
        need_all = self.settings.heuristic or self.settings.nll_floor is None
        if need_all:
            self._ensure_vertices(np.arange(self.roadmap.n))
        if self._known_shift is not None:
            shift = self._known_shift
        else:
            shift = np.asarray(min(0.0, float(np.min(self._vraw))) if self.roadmap.n else 0.0)
        if self._shift is None or not np.array_equal(shift, self._shift):
            self._shift = shift
            self._out, self._tout, self._tedge = {}, {}, {}
            self._ehave[:] = False
        if self._graph_size != self.roadmap.graph.number_of_nodes():  # grown: stale adjacency
            self._graph_size = self.roadmap.graph.number_of_nodes()
            adj = self.roadmap.graph.adj
            for v in [v for v, a in self._adjc.items() if len(adj[v]) != len(a[0])]:
                del self._adjc[v]
                self._out.pop(v, None)
        for v in self._temp:
            self._raw(v)
        if self.settings.heuristic:
            self._heuristic_table(t_start)
        else:
            self._G = None

    def ell(self, raw: np.ndarray) -> np.ndarray:
        """Shifted, non-negative step cost of raw values ``(..., T)``."""
        return np.maximum(raw - self._shift, 0.0)

    def _relaxed_edges(self):
        """(src, dst, tau) of every roadmap edge in both directions, sorted by src (cached)."""
        n = self.roadmap.n
        if self._relaxed is None or self._relaxed[0] != n:
            E = np.array(list(self.roadmap.graph.edges), dtype=int).reshape(-1, 2)
            src = np.concatenate([E[:, 0], E[:, 1]])
            dst = np.concatenate([E[:, 1], E[:, 0]])
            order = np.argsort(src, kind="stable")
            src, dst = src[order], dst[order]
            V = self.roadmap._buf
            tau = np.max(np.abs(V[dst] - V[src]) / self.vmax, axis=1) if len(src) else np.zeros(0)
            self._relaxed = (n, src, dst, tau, self._subintervals(tau))
        return self._relaxed[1:]

    def _subintervals(self, tau: np.ndarray) -> np.ndarray:
        """Quadrature sub-intervals m (the rule of ``_integrate``) for traversal times tau."""
        return np.maximum(1, np.ceil(tau / self.quad_dt - 1e-9)).astype(int)

    def _tau(self, v: int, ws) -> np.ndarray:
        Q = np.array([self.position(w) for w in ws]).reshape(len(ws), self.roadmap.d)
        return np.max(np.abs(Q - self.position(v)) / self.vmax, axis=1)

    def _heuristic_table(self, t_start: int) -> None:
        """Consistent A* bounds (lfd.stheuristic) for the roadmap, the goal and the start."""
        n = self.roadmap.n
        sinks = [i for i in sorted(self._temp) if self._in[i]]
        key = (self._epoch, n, self._shift.tobytes(), self.settings.heuristic_sweeps,
               tuple((i, self._temp[i].tobytes(), tuple(self._in[i]), tuple(self._links[i]))
                     for i in sinks))
        if key != self._Gkey or t_start < self._Gtmin:
            self._Grow = {i: n + j for j, i in enumerate(sinks)}
            ell = self.ell(np.concatenate([self._vraw[:n]] + [self._raw(i)[None] for i in sinks]))
            xs, xd, xt = [], [], []
            for i in sinks:
                xs += self._in[i]
                xd += [self._Grow[i]] * len(self._in[i])
                xt.append(self._tau(i, self._in[i]))
                out = [w for w in self._links[i] if w >= 0 or w in self._Grow]
                xs += [self._Grow[i]] * len(out)
                xd += [w if w >= 0 else self._Grow[w] for w in out]
                xt.append(self._tau(i, out))
            xt = np.concatenate(xt) if xs else None
            extra = (np.array(xs, dtype=int), np.array(xd, dtype=int), xt,
                     self._subintervals(xt)) if xs else None
            src, dst, tau, m = self._relaxed_edges()
            self._G = relaxed_cost_to_go(ell, self.trans, self.time_offsets, self.dt, src, dst,
                                         tau, m, self.settings.heuristic_sweeps, extra, t_start,
                                         dwell=self._dwell_terms)
            self._Gell, self._Gkey, self._Gtmin = ell, key, t_start
        self._Gsrc = {}
        for i in self._temp:
            if i not in self._Grow:
                out = [w for w in self._links[i] if w >= 0 or w in self._Grow]
                rows = np.array([w if w >= 0 else self._Grow[w] for w in out], dtype=int)
                tau = self._tau(i, out)
                self._Gsrc[i] = source_bound(self.ell(self._raw(i)), self._G, self._Gell, rows,
                                             tau, self._subintervals(tau), self.trans,
                                             self.time_offsets, self.dt,
                                             dwell=self._dwell_terms)

    def heuristic_fn(self) -> Callable | None:
        """``h(node, target) -> float`` for networkx (None when disabled): ``heuristic`` over
        Python lists, built once per plan, because A* calls it on every push."""
        if self._G is None:
            return None
        rows = self._G.tolist()
        temp = {i: (self._Gsrc[i].tolist() if i in self._Gsrc else rows[self._Grow[i]])
                for i in self._temp}

        def h(node, _target=None) -> float:
            v, t = node
            if v >= 0:
                return rows[v][t]
            return temp[v][t] if v in temp else 0.0  # the SINK node
        return h

    def heuristic(self, v: int, t: int) -> float:
        """Consistent lower bound on the cost from ``(v, t)`` to step T-1 (0 when disabled)."""
        if self._G is None:
            return 0.0
        if v >= 0:
            return float(self._G[v, t])
        return float(self._Gsrc[v][t]) if v in self._Gsrc else float(self._G[self._Grow[v], t])

    def time_cost(self, v: int, t: int, k: int) -> float:
        """Cost of the time edge ``(v, t) -> (v, t + k)``; inf when not permitted."""
        c = self.trans[t, k]
        if not np.isfinite(c):
            return math.inf
        ell = self.ell(self._raw(v))
        return float(c + ell[t + k] + dwell_charge(ell.__getitem__, t, k, self._dwell_terms))

    def spatial(self, v: int) -> tuple[list[int], np.ndarray]:
        """Collision-free neighbours of ``v`` and their edge costs ``(deg, T)`` at every step.

        For a roadmap vertex: its roadmap neighbours (unknown edges are collision-checked now
        with ``edge_checks="expand"``, assumed free with "path");
        for a temporary vertex: the vertices it is joined to. Cached per landmark set (roadmap
        vertices, by edge id) or per plan (temporary vertices).
        """
        hit = self._out.get(v)
        if hit is not None:
            return hit
        if v < 0:
            nbrs = self._links.get(v, [])
            hit = self._out[v] = (nbrs, self._temp_table(v, nbrs))
            return hit
        a = self._adjc.get(v)
        if a is None:
            if self.settings.edge_checks == "expand":
                nbrs = self.roadmap.free_neighbors(v)
            else:  # unchecked edges count as free until a path uses them (see drop_edge)
                nbrs = list(self.roadmap.graph.adj[v])
            adj = self.roadmap.graph.adj[v]
            a = self._adjc[v] = (nbrs, np.array(nbrs, dtype=int),
                                 np.array([adj[w]["eid"] for w in nbrs], dtype=int))
        nbrs, W, eids = a
        if len(self._ehave) < self.roadmap.n_edge_ids:  # the roadmap grew
            extra = self.roadmap.n_edge_ids - len(self._ehave)
            self._ehave = np.concatenate([self._ehave, np.zeros(extra, dtype=bool)])
            self._ecost = np.concatenate([self._ecost, np.empty((extra, self.T))])
        miss = ~self._ehave[eids]
        if miss.any():
            self._ecost[eids[miss]] = self._integrate(v, W[miss])
            self._ehave[eids[miss]] = True
        hit = self._out[v] = (nbrs, self._ecost[eids])
        return hit

    def drop_edge(self, u: int, w: int) -> None:
        """Forget the cached adjacency of ``u`` and ``w`` after their edge left the roadmap (it
        collided); the edge-cost cache is keyed by edge id and stays valid for the others."""
        for v in (u, w):
            self._adjc.pop(v, None)
            self._out.pop(v, None)

    def has_vertex(self, v: int) -> bool:
        """Whether ``v`` is a roadmap vertex or a current temporary vertex."""
        return 0 <= v < self.roadmap.n or v in self._temp

    def joins_temporary(self, v: int) -> bool:
        """Whether roadmap vertex ``v`` has edges to temporary vertices in this plan."""
        return v in self._back

    def temporary_spatial(self, v: int) -> tuple[list[int], np.ndarray]:
        """Edges from roadmap vertex ``v`` to the temporary vertices joined to it (per plan)."""
        hit = self._tout.get(v)
        if hit is None:
            nbrs = self._back.get(v, [])
            hit = self._tout[v] = (nbrs, self._temp_table(v, nbrs))
        return hit

    def _temp_table(self, v: int, nbrs: list[int]) -> np.ndarray:
        """Costs ``(len(nbrs), T)`` of the per-plan edges ``v-w`` (one of them temporary)."""
        C = np.empty((len(nbrs), self.T))
        todo = []
        for i, w in enumerate(nbrs):
            vec = self._tedge.get((v, w) if v < w else (w, v))
            if vec is None:
                todo.append(i)
            else:
                C[i] = vec
        if todo:
            C[todo] = self._integrate(v, [nbrs[i] for i in todo])
            for i in todo:
                w = nbrs[i]
                self._tedge[(v, w) if v < w else (w, v)] = C[i]
        return C

    def _integrate(self, v: int, W) -> np.ndarray:
        """Costs ``(E, T)`` of the edges ``v-w``, w in ``W``: one ``step_nll`` call for all
        interior quadrature nodes (trapezoid rule, see the module docstring)."""
        W = list(W) if not isinstance(W, np.ndarray) else W
        roadmap_only = min(W) >= 0
        if roadmap_only:
            self._ensure_vertices(np.append(W, v) if v >= 0 else W)
            QW = self.roadmap._buf[W]
        else:
            QW = np.array([self.position(w) for w in W])  # (E, d)
        qv = self.position(v)
        tau = np.max(np.abs(QW - qv) / self.vmax, axis=1)  # (E,) traversal times
        m = self._subintervals(tau)  # (E,) quadrature sub-intervals
        n_in = m - 1
        sums = np.zeros((len(W), self.T))  # sum of ell over each edge's interior nodes
        if n_in.sum():
            edge = np.repeat(np.arange(len(W)), n_in)  # interior node -> edge
            first = np.cumsum(n_in) - n_in  # index of each edge's first interior node
            frac = (np.arange(len(edge)) - first[edge] + 1) / m[edge]  # (N,) in (0, 1)
            P = qv + (QW[edge] - qv) * frac[:, None]  # (N, d)
            Lin = self.ell(self._eval(P))  # (N, T)
            has = n_in > 0
            sums[has] = np.add.reduceat(Lin, first[has], axis=0)
        self.counters["edges"] += len(W)
        ev = self.ell(self._raw(v))  # (T,)
        EW = self.ell(self._vraw[W] if roadmap_only else np.array([self._raw(w) for w in W]))
        mean = (0.5 * (ev[None] + EW) + sums) / m[:, None]  # trapezoid rule, (E, T)
        with np.errstate(invalid="ignore"):
            vecs = (tau / self.dt)[:, None] * (self.trans[None, :, 0] + mean)
        vecs[np.isnan(vecs)] = np.inf  # tau = 0 with a forbidden self-transition
        return vecs
