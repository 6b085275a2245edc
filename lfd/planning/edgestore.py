"""Edge state of the spatiotemporal roadmap: costs and collision validity, in one owner.

``EdgeStore`` keeps, for every edge ``e = (u, w)`` of a ``lfd.planning.roadmap.Roadmap`` (row = edge id):

* its traversal time ``tau[e] = max_j |q_w - q_u|_j / vmax_j`` at the joint velocity limits and
  its ``m[e] = max(1, ceil(tau / quad_dt))`` quadrature sub-intervals, whose ``m - 1`` interior
  configurations are prepared once by the step cost (``lfd.planning.stepcost``: FK and everything else
  that does not depend on the landmarks; summed per edge when the step cost can, ``prepare_sums``);
* its cost at every time step, the line integral of the paper's Sec. V-B over the motion::

      W[e, t] = (tau / dt) * (stay[t] + mean_s ell(q(s), t))

  (``stay[t] = -log p(t | t)`` in the step cost's units, the mean by the trapezoid rule over the
  ``m + 1`` nodes), computed for all edges and steps in a few array operations when first asked
  for after new landmarks, and for the new ones only after the roadmap grew;
* its collision state: ``UNKNOWN`` (not checked, or checked before a nearby object moved),
  ``FREE`` or ``BLOCKED``, and for a blocked edge a *witness* when one is known: the
  configuration found colliding (a quadrature node of the construction's or the search's point
  screens, or an end vertex; the segment check does not say where it hit), and what the witness
  hit when the collision callables name it (``lfd.planning.roadmap.Roadmap.hits``).

One method changes what is known: ``invalidate(landmarks=..., vacated=..., occupied=...)``. New
landmarks make every cost stale (recomputed in one batch on the next ``costs()``). An object that
moved leaves a ball (``vacated``, its old place) and takes another (``occupied``): an object that
leaves cannot make a motion collide, so only the blocked edges it may have blocked are reset (at
once, so that the search may use them again): those whose witness lies near the vacated ball
(without a witness, whose motion passes near it), except those whose witness is known to have
hit something else than the object that left (the table under it, a neighbour: 96-98% of the
witnesses near a bowl that left, measured; docs/EXPERIMENTS.md, *What a witness hit*). Their
witness is the first thing ``screen`` and ``check`` test, one configuration that settles most of them (what else they hit -- the table, a
neighbouring object -- is usually still there). An object that arrives cannot free a
motion, so only the free (and screened) edges passing near the occupied ball become stale, and
lazily: ``check`` and ``screen`` test the edges a path reaches against the balls occupied since
they were settled. The work of a move is proportional to the path, not to the roadmap. The swept box of an edge bounds the ``keypoint_fn`` points (e.g. link origins and the tool
point) at all its quadrature nodes, grown by ``sweep_margin`` (link radius, tool extent) and
half a node spacing. ``check(eids)`` settles unknown edges with the roadmap's ``segment_fn``.

Vertex step costs ``ell (n, T)`` come with the edge costs: a time edge ``(v, t) -> (v, t + k)``
costs ``trans[t, k] + ell[v, t + k]`` (``lfd.planning.stsearch``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from lfd.planning.quadrature import MIN_QUAD_DT, interior_points, interior_sums, trapezoid_costs
from lfd.planning.roadmap import UNNAMED, Roadmap
from lfd.planning.stepcost import StepCost, SummedStepCost

__all__ = ["BLOCKED", "FREE", "UNKNOWN", "EdgeStore"]

UNKNOWN, FREE, BLOCKED = 0, 1, 2


def _cat(parts: list[tuple[torch.Tensor, ...] | None]) -> tuple[torch.Tensor, ...] | None:
    kept = [p for p in parts if p is not None]
    if not kept:
        return None
    return tuple(torch.cat(xs) for xs in zip(*kept)) if len(kept) > 1 else kept[0]


def _polyline_distance(K: np.ndarray, c: np.ndarray) -> np.ndarray:
    """``(N,)`` distance from ``c (3,)`` to each polyline of keypoints ``K (N, K, 3)``."""
    a, ab = K[:, :-1], np.diff(K, axis=1)  # (N, K-1, 3) link segments
    s = np.clip(((c - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0.0, 1.0)
    return np.linalg.norm(a + s[..., None] * ab - c, axis=-1).min(1)


class EdgeStore:
    """Costs and collision states of ``roadmap``'s edges (see the module docstring).

    Parameters
    ----------
    roadmap : the Roadmap (it may grow; ``sync`` picks new vertices and edges up).
    step_cost : a ``lfd.planning.stepcost.StepCost``.
    stay : (T,) cost of one sampling interval spent in step t (``-log p(t | t)``, inf = forbidden).
    dt : sampling interval (s); vmax : (d,) joint velocity limits; quad_dt : time between
    quadrature nodes (default dt, or ``MIN_QUAD_DT`` if dt is shorter: the mean cost along an
    edge needs nodes as fine as its motion, not as the recordings' rate).
    keypoint_fn : optional ``Q (N, d) -> (N, K, 3)`` points swept by the robot (for the balls
        of ``invalidate``; without it every edge is near every ball).
    sweep_margin : m added around the keypoints' box of an edge.
    """

    def __init__(self, roadmap: Roadmap, step_cost: StepCost, stay, dt: float, vmax, quad_dt: float | None = None,
                 keypoint_fn: Callable | None = None, sweep_margin: float = 0.15):
        self.roadmap, self.step_cost = roadmap, step_cost
        self.stay = np.asarray(stay, dtype=float).reshape(-1)
        self.T = len(self.stay)
        self.dt = float(dt)
        self.vmax = np.asarray(vmax, dtype=float).reshape(-1)
        if not self.dt > 0 or self.vmax.shape != (roadmap.d,) or not np.all(self.vmax > 0):
            raise ValueError(f"Expected dt > 0 and vmax ({roadmap.d},) > 0, got {dt}, {vmax}")
        self.quad_dt = float(quad_dt) if quad_dt else max(self.dt, MIN_QUAD_DT)
        self.keypoint_fn, self.sweep_margin = keypoint_fn, float(sweep_margin)
        self.ends = np.empty((0, 2), dtype=np.int64)  # (E, 2)
        self.tau = np.empty(0)
        self.m = np.empty(0, dtype=np.int64)
        self.state = np.empty(0, dtype=np.int8)
        self._first = np.empty(0, dtype=np.int64)  # (E,) first interior row of each edge
        self._vparts: tuple | None = None
        self._pparts: tuple | None = None  # the interior nodes' parts (a step cost that cannot sum), or
        self._sparts: tuple | None = None  # per edge, summed over its interior nodes (``prepare_sums``)
        # edges' costs from their nodes' summed parts when the step cost can sum them (one
        # evaluation per edge on a landmark move; measured in docs/EXPERIMENTS.md, *Edge costs
        # from summed parts*), else from every node
        self._summed: SummedStepCost | None = None
        if isinstance(step_cost, SummedStepCost) and \
                step_cost.prepare_sums(np.empty((0, roadmap.d)), np.empty(0, dtype=np.int64)) is not None:
            self._summed = step_cost
        self._n_points = 0
        self._box = np.empty((0, 2, 3))  # (E, 2, 3) swept boxes (with keypoint_fn)
        self._vkey = np.empty((0, 0, 3))  # (n, K, 3) vertex keypoints
        self._pkey = np.empty((0, 0, 3))  # (P, K, 3) interior-node keypoints
        self._screened = np.empty(0, dtype=bool)  # (E,) midpoint checked since the last reset
        # a configuration found colliding on each blocked edge (a witness), when one is known: an
        # interior node (row of the interior nodes) or an end vertex; -1 where none
        self._wnode = np.empty(0, dtype=np.int64)  # (E,)
        self._wvert = np.empty(0, dtype=np.int64)  # (E,)
        self._wwhat = np.empty(0, dtype=np.int64)  # (E,) what the witness hit: a code of ``_names``, -1 unnamed
        self._names: dict[str, int] = {}
        self._vscreened = np.empty(0, dtype=bool)  # (n,) vertex checked since a nearby object moved
        self._regions: list[tuple[np.ndarray, float]] = []  # balls objects moved into
        self._epoch = np.empty(0, dtype=np.int64)  # (E,) regions an edge's state and screen account for
        self._landmarks = None
        self._costs: tuple[np.ndarray, np.ndarray] | None = None
        self.counters = {"costed_edges": 0, "segment_checks": 0, "blocked": 0, "invalidated": 0,
                         "screened_points": 0, "witness_checks": 0}
        self.sync()

    # ------------------------------------------------------------------ structure
    @property
    def n_vertices(self) -> int:
        return 0 if self._vparts is None else len(self._vparts[0])

    def sync(self) -> None:
        """Take in the vertices and edges the roadmap gained since the last call (the first
        call's edges screened at every quadrature node, later ones left unscreened)."""
        rm = self.roadmap
        V = rm.vertices
        n0 = self.n_vertices
        if rm.n > n0:
            self._vparts = _cat([self._vparts, self.step_cost.prepare(V[n0:])])
            self._vscreened = np.concatenate([self._vscreened, np.ones(rm.n - n0, dtype=bool)])  # checked on insertion
            if self.keypoint_fn is not None:
                k = np.asarray(self.keypoint_fn(V[n0:]), dtype=float)
                self._vkey = k if n0 == 0 else np.concatenate([self._vkey, k])
        ends = rm.edge_array()
        e0 = len(self.ends)
        if len(ends) == e0:
            return
        new = ends[e0:]
        Qa, Qb = V[new[:, 0]], V[new[:, 1]]
        tau = np.max(np.abs(Qb - Qa) / self.vmax, axis=1)
        m = np.maximum(1, np.ceil(tau / self.quad_dt - 1e-9)).astype(np.int64)
        P, first = interior_points(Qa, Qb, m)
        state = np.zeros(len(new), dtype=np.int8)
        wnode = np.full(len(new), -1, dtype=np.int64)
        wwhat = np.full(len(new), -1, dtype=np.int64)
        # the store's first edges (the roadmap as built) are screened at every quadrature node;
        # edges a regrowth adds are left to the search's screens (``screen``) and segment checks:
        # their node screen sat on the anytime re-plan's critical path (docs/EXPERIMENTS.md,
        # *Witnesses*, the regrowth's edges)
        screen_all = e0 == 0
        if len(P) and screen_all:
            what = self.roadmap.hits(P)
            hit = np.flatnonzero(what != "")
            owner = np.repeat(np.arange(len(new)), m - 1)[hit]
            state[owner] = BLOCKED
            # an edge hit at several nodes keeps its last as the witness
            last = len(owner) - 1 - np.unique(owner[::-1], return_index=True)[1]
            wnode[owner[last]] = hit[last] + self._n_points
            wwhat[owner[last]] = self._codes(what[hit[last]])
            self.counters["screened_points"] += len(P)
        if self._summed is not None:
            self._sparts = _cat([self._sparts, self._summed.prepare_sums(P, m - 1)])
        else:
            self._pparts = _cat([self._pparts, self.step_cost.prepare(P)])
        self._first = np.concatenate([self._first, first + self._n_points])
        self._n_points += len(P)
        if self.keypoint_fn is not None:
            kp = np.asarray(self.keypoint_fn(P), dtype=float).reshape(len(P), self._vkey.shape[1], 3)
            self._pkey = kp if len(self._pkey) == 0 else np.concatenate([self._pkey, kp])
            self._box = np.concatenate([self._box, self._boxes(new, kp, first, m)])
        self._screened = np.concatenate([self._screened, np.full(len(new), screen_all)])
        self._wnode = np.concatenate([self._wnode, wnode])
        self._wvert = np.concatenate([self._wvert, np.full(len(new), -1, dtype=np.int64)])
        self._wwhat = np.concatenate([self._wwhat, wwhat])
        self._epoch = np.concatenate([self._epoch, np.full(len(new), len(self._regions))])
        self.ends, self.tau, self.m = np.concatenate([self.ends, new]), np.concatenate([self.tau, tau]), \
            np.concatenate([self.m, m])
        self.state = np.concatenate([self.state, state])

    def _half_spacing(self, ends: np.ndarray, m: np.ndarray) -> np.ndarray:
        """``(E',)`` half the largest keypoint displacement between consecutive quadrature nodes
        (from the end vertices: the keypoints' chord over ``m`` sub-intervals): how far a swept
        point can be from the nearest node."""
        ka, kb = self._vkey[ends[:, 0]], self._vkey[ends[:, 1]]
        return 0.5 * np.linalg.norm(kb - ka, axis=-1).max(1) / m

    def _boxes(self, new: np.ndarray, kp: np.ndarray, first: np.ndarray, m: np.ndarray) -> np.ndarray:
        """``(E', 2, 3)`` swept boxes of new edges (``kp (P, K, 3)``: their interior keypoints)."""
        ka, kb = self._vkey[new[:, 0]], self._vkey[new[:, 1]]  # (E', K, 3)
        lo, hi = np.minimum(ka, kb).min(1), np.maximum(ka, kb).max(1)  # (E', 3)
        if len(kp):
            has = m > 1
            lo[has] = np.minimum(lo[has], np.minimum.reduceat(kp.min(1), first[has], axis=0))
            hi[has] = np.maximum(hi[has], np.maximum.reduceat(kp.max(1), first[has], axis=0))
        grow = self.sweep_margin + self._half_spacing(new, m)
        return np.stack([lo - grow[:, None], hi + grow[:, None]], axis=1)

    # ------------------------------------------------------------------ state changes
    def invalidate(self, landmarks=None, vacated: tuple | None = None, occupied: tuple | None = None) -> int:
        """The one way edge knowledge becomes stale.

        ``landmarks``: new landmark poses (whatever the step cost takes): every cost is stale.
        ``vacated``, ``occupied``: ``(centre (3,), radius)`` in the keypoints' frame, a ball an
        object left or now takes; ``vacated`` may name the object, ``(centre, radius, name)``,
        with the name the collision callables give it (``Roadmap.hits``; a name they never give
        keeps every named witness blocked). Blocked edges whose witness (else whose
        motion) passes near a vacated ball are reset to ``UNKNOWN`` now, unless their witness hit
        something known to be another than the named object; free and screened edges passing
        near an occupied ball are judged again when a path or its screen reaches them
        (``check``, ``screen``). Returns the number of edges reset now.
        """
        if landmarks is not None:
            self._landmarks, self._costs = landmarks, None
        reset = np.zeros(0, dtype=np.int64)
        if vacated is not None:
            if len(vacated) not in (2, 3):
                raise ValueError(f"Expected vacated = (centre, radius) or (centre, radius, name), got {vacated!r}")
            c, r = np.asarray(vacated[0], dtype=float).reshape(3), float(vacated[1])
            blocked = np.flatnonzero(self.state == BLOCKED)
            if len(vacated) == 3 and vacated[2]:  # what hit another object stays blocked
                what = self._wwhat[blocked]
                blocked = blocked[(what < 0) | (what == self._names.get(str(vacated[2]), -2))]
            reset = blocked[self._near_witness(blocked, c, r)]
            self.state[reset] = UNKNOWN  # the witness stays: ``screen`` and ``check`` try it first
            self._screened[reset] = False
            self.counters["invalidated"] += len(reset)
        if occupied is not None:
            self._regions.append((np.asarray(occupied[0], dtype=float).reshape(3), float(occupied[1])))
        return len(reset)

    def _near(self, eids: np.ndarray, c: np.ndarray, r: float) -> np.ndarray:
        """``(len(eids),)`` bool: the edge's motion passes within ``r`` of ``c`` (swept box, then
        the keypoint polyline at every quadrature node); all True without ``keypoint_fn``."""
        if self.keypoint_fn is None:
            return np.ones(len(eids), dtype=bool)
        box = self._box[eids]
        gap = np.maximum(np.maximum(box[:, 0] - c, c - box[:, 1]), 0.0)
        near = np.linalg.norm(gap, axis=1) <= r
        if near.any():
            near[near] = self._polyline_near(eids[near], c, r)
        return near

    def _near_witness(self, eids: np.ndarray, c: np.ndarray, r: float) -> np.ndarray:
        """``(len(eids),)`` bool, for blocked edges: what made the edge collide may have been
        within ``r`` of ``c``. With a witness (a configuration found colliding on it), its keypoint
        polyline passes within ``r + sweep_margin`` of ``c``; without one, the edge's motion does
        (``_near``)."""
        if self.keypoint_fn is None:
            return np.ones(len(eids), dtype=bool)
        wn, wv = self._wnode[eids], self._wvert[eids]
        by_node, by_vertex = wn >= 0, (wn < 0) & (wv >= 0)
        rest = ~(by_node | by_vertex)
        near = np.zeros(len(eids), dtype=bool)
        near[by_node] = _polyline_distance(self._pkey[wn[by_node]], c) <= r + self.sweep_margin
        near[by_vertex] = _polyline_distance(self._vkey[wv[by_vertex]], c) <= r + self.sweep_margin
        near[rest] = self._near(eids[rest], c, r)
        return near

    def _refresh(self, eids: np.ndarray) -> None:
        """Bring the edges ``eids`` (unique) up to date with the balls occupied since they were
        last settled: free ones passing near one become ``UNKNOWN`` and are screened again, as
        are their end vertices."""
        K = len(self._regions)
        stale = eids[self._epoch[eids] < K]
        if len(stale) == 0:
            return
        hit = np.zeros(len(stale), dtype=bool)
        for j in range(int(self._epoch[stale].min()), K):
            sel = np.flatnonzero((self._epoch[stale] <= j) & ~hit)
            if len(sel):
                c, r = self._regions[j]
                hit[sel] = self._near(stale[sel], c, r)
        near = stale[hit]
        reset = near[self.state[near] == FREE]
        self.state[reset] = UNKNOWN
        self._screened[near] = False
        self._vscreened[self.ends[near].ravel()] = False
        self._epoch[stale] = K
        self.counters["invalidated"] += len(reset)

    def _polyline_near(self, eids: np.ndarray, c: np.ndarray, r: float) -> np.ndarray:
        """``(len(eids),)`` bool: some node of the edge has its keypoint polyline (the arm's links,
        then the tool) within ``r`` + ``sweep_margin`` + half a node spacing of ``c``."""
        u, w, m = self.ends[eids, 0], self.ends[eids, 1], self.m[eids]
        first = self._first[eids]
        cnt = m - 1
        owner = np.repeat(np.arange(len(eids)), cnt)
        pidx = np.repeat(first, cnt) + np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        K = np.concatenate([self._vkey[u], self._vkey[w], self._pkey[pidx]])  # (N, K, 3)
        who = np.concatenate([np.arange(len(eids)), np.arange(len(eids)), owner])
        dist = _polyline_distance(K, c)  # (N,)
        best = np.full(len(eids), np.inf)
        np.minimum.at(best, who, dist)
        return best <= r + self.sweep_margin + self._half_spacing(self.ends[eids], m)

    def screen(self, eids) -> int:
        """Point-check one configuration of each unknown, unscreened edge among ``eids`` in one
        batch (``roadmap.hits``): its witness if it has one, else its middle quadrature
        node (the midpoint when ``m`` is even); those that collide become ``BLOCKED``. A cheap
        first look near a collision; the segment check stays the final word. Returns how many
        were blocked.

        One point per edge, not every quadrature node: measured on the pour's reaction to a moved
        bowl (docs/EXPERIMENTS.md, *The point screen: one point per edge*), the nodes cost twice
        the segment checks they saved; the midpoint keeps nearly all of the screen's effect on the
        number of searches."""
        eids = np.unique(np.asarray(eids, dtype=np.int64))
        self._refresh(eids)
        eids = eids[(self.state[eids] == UNKNOWN) & ~self._screened[eids]]
        self._screened[eids] = True
        verts = np.unique(self.ends[eids])
        verts = verts[~self._vscreened[verts]]
        if len(verts):  # a vertex an object moved onto blocks every edge it has
            self._vscreened[verts] = True
            what = self.roadmap.hits(self.roadmap.vertices[verts])
            for v, w in zip(verts.tolist(), what.tolist()):
                if w:
                    self.set_blocked(self.incident(v), at_vertex=v, what=w)
            eids = eids[self.state[eids] == UNKNOWN]
        eids = eids[(self.m[eids] > 1) | self._witnessed(eids)]
        if len(eids) == 0:
            return 0
        self.counters["screened_points"] += len(eids)
        Q, wn, wv = self._probe(eids)
        what = self.roadmap.hits(Q)
        hit = what != ""
        self._block(eids[hit], wn[hit], wv[hit], self._codes(what[hit]))
        return int(hit.sum())

    def _witnessed(self, eids: np.ndarray) -> np.ndarray:
        """``(len(eids),)`` bool: the edge has a witness."""
        return (self._wnode[eids] >= 0) | (self._wvert[eids] >= 0)

    def _probe(self, eids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The point to check first on each edge: its witness (a configuration found colliding
        on it before) if it has one, else its middle quadrature node (the midpoint when m is even;
        m > 1). ``(Q (n, d), wnode (n,), wvert (n,))``: the configurations and, as witnesses,
        their interior rows or vertices (-1 where not)."""
        wn, wv = self._wnode[eids].copy(), self._wvert[eids].copy()
        mid = (wn < 0) & (wv < 0)
        wn[mid] = self._first[eids[mid]] + self.m[eids[mid]] // 2 - 1
        by_vertex = wn < 0
        Q = self._node_configurations(eids, np.where(by_vertex, 0, wn - self._first[eids] + 1))
        Q[by_vertex] = self.roadmap.vertices[wv[by_vertex]]
        return Q, wn, wv

    def _node_configurations(self, eids: np.ndarray, k: np.ndarray) -> np.ndarray:
        """``(len(eids), d)``: quadrature node ``k`` (``0..m``) of each edge."""
        V = self.roadmap.vertices
        u, w = V[self.ends[eids, 0]], V[self.ends[eids, 1]]
        return u + (w - u) * (k / self.m[eids])[:, None]

    def incident(self, v: int) -> np.ndarray:
        """``(deg,)`` the ids of the edges at vertex ``v``."""
        return np.fromiter((e for _, _, e in self.roadmap.graph.edges(int(v), data="eid")), dtype=np.int64)

    def set_blocked(self, eids, at_vertex: int | None = None, what: str | None = None) -> None:
        """Mark edges as colliding; ``at_vertex``: their end vertex found in collision, if that
        is why (a witness: ``invalidate`` resets such an edge only when an object leaves near
        that vertex), and ``what`` it hit, if known (``Roadmap.hits``)."""
        eids = np.asarray(eids, dtype=np.int64)
        self._block(eids, -1, -1 if at_vertex is None else int(at_vertex),
                    self._codes(np.array([what or UNNAMED]))[0])

    def _codes(self, what: np.ndarray) -> np.ndarray:
        """``(n,)`` codes of the names ``what (n,)`` (``Roadmap.hits``; -1 for ``UNNAMED``)."""
        for name in set(what.tolist()) - self._names.keys() - {UNNAMED}:
            self._names[name] = len(self._names)
        return np.array([self._names.get(w, -1) for w in what.tolist()], dtype=np.int64)

    def _block(self, eids: np.ndarray, wnode, wvert, wwhat) -> None:
        """Mark ``eids`` as colliding with their witnesses (interior rows, vertices; -1 where
        none) and what those hit (codes, -1 where unnamed)."""
        self.counters["blocked"] += int((self.state[eids] != BLOCKED).sum())
        self.state[eids] = BLOCKED
        self._wnode[eids], self._wvert[eids], self._wwhat[eids] = wnode, wvert, wwhat

    def check(self, eids) -> np.ndarray:
        """Settle the collision state of ``eids`` (unknown ones checked now: the witness first,
        if any, then the segment); ``(len,)`` bool free."""
        eids = np.asarray(eids, dtype=np.int64).reshape(-1)
        self._refresh(np.unique(eids))
        V = self.roadmap.vertices
        todo = np.unique(eids[self.state[eids] == UNKNOWN])
        known = todo[self._witnessed(todo)]
        if len(known):  # a configuration that collided before, checked first
            Q, wn, wv = self._probe(known)
            self.counters["witness_checks"] += len(known)
            what = self.roadmap.hits(Q)
            again = what != ""
            self._block(known[again], wn[again], wv[again], self._codes(what[again]))  # the witness kept
        for e in todo[self.state[todo] == UNKNOWN].tolist():
            self._wnode[e] = self._wvert[e] = self._wwhat[e] = -1
            u, w = self.ends[e]
            self.counters["segment_checks"] += 1
            hit = self.roadmap.segment_collides(V[u], V[w])
            self.state[e] = BLOCKED if hit else FREE
            self.counters["blocked"] += int(hit)
        return self.state[eids] == FREE

    # ------------------------------------------------------------------ costs
    def costs(self) -> tuple[np.ndarray, np.ndarray]:
        """``(ell (n, T), W (E, T))`` for the current landmarks, computed now if stale: all of them
        after new landmarks, only the new vertices' and edges' after the roadmap grew (a growth
        round's re-plan otherwise costed the whole roadmap again). May raise ``LookupError`` or
        ``lfd.planning.stepcost.CostError`` from the step cost."""
        if self._landmarks is None:
            raise LookupError("no landmarks yet: call invalidate(landmarks=...) first")
        if self._costs is None:
            self._costs = self._evaluate(0, 0, np.zeros((0, self.T)))
        elif len(self._costs[1]) < len(self.ends) or len(self._costs[0]) < self.n_vertices:
            ell, W = self._costs
            ell, W_new = self._evaluate(len(ell), len(W), ell)
            self._costs = (ell, np.concatenate([W, W_new]))
        return self._costs

    def _evaluate(self, v0: int, e0: int, ell_old: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Step costs of the vertices from ``v0`` on, appended to ``ell_old (v0, T)``, and the
        costs ``(E - e0, T)`` of the edges from ``e0`` on: ``(ell (n, T), W (E - e0, T))``."""
        def rows(parts, start):  # the parts of rows ``start..`` (every part is row-aligned)
            return tuple(p[start:] for p in parts)

        ell = ell_old
        if self.n_vertices > v0:
            ell = np.concatenate([ell_old, self.step_cost.evaluate(rows(self._vparts, v0), self._landmarks)])
        m = self.m[e0:]
        if self._summed is not None:
            sums = (self._summed.evaluate_sums(rows(self._sparts, e0), self._landmarks)
                    if self._sparts is not None and len(m) else np.zeros((len(m), self.T)))
        else:
            p0 = int(self._first[e0]) if len(m) else self._n_points  # the first new edge's first interior row
            ell_in = (self.step_cost.evaluate(rows(self._pparts, p0), self._landmarks) if self._n_points > p0
                      else np.zeros((0, self.T)))
            sums = interior_sums(ell_in, self._first[e0:] - p0, m)
        u, w = self.ends[e0:, 0], self.ends[e0:, 1]
        self.counters["costed_edges"] += len(m)
        return ell, trapezoid_costs(ell[u], ell[w], sums, m, self.tau[e0:], self.stay, self.dt)

    def segment_costs(self, q: np.ndarray, Qb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Costs of motions not in the roadmap, from ``q (d,)`` to each of ``Qb (k, d)``, for the
        current landmarks: ``(ell_q (T,), W (k, T))`` (symmetric: also the cost back to ``q``)."""
        if self._landmarks is None:
            raise LookupError("no landmarks yet: call invalidate(landmarks=...) first")
        q = np.asarray(q, dtype=float).reshape(1, -1)
        Qb = np.asarray(Qb, dtype=float).reshape(-1, q.shape[1])
        Qa = np.broadcast_to(q, Qb.shape)
        tau = np.max(np.abs(Qb - Qa) / self.vmax, axis=1)
        m = np.maximum(1, np.ceil(tau / self.quad_dt - 1e-9)).astype(np.int64)
        P, first = interior_points(Qa, Qb, m)
        ell = self.step_cost.evaluate(self.step_cost.prepare(np.concatenate([q, Qb, P])), self._landmarks)
        k = len(Qb)
        W = trapezoid_costs(np.broadcast_to(ell[0], (k, self.T)), ell[1:k + 1], interior_sums(ell[k + 1:], first, m),
                            m, tau, self.stay, self.dt)
        return ell[0], W
