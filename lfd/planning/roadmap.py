"""PRM* over joint space, built from callables (no robot, no simulator).

The roadmap only knows three callables, in the style of caelan/motion-planners:

* ``sample_fn(n) -> (n, d)`` array of configurations (e.g. uniform within joint limits);
* ``collision_fn(q: (d,)) -> bool`` (True = in collision), or ``batch_collision_fn(Q: (n, d)) ->
  (n,) bool``; either may instead name what a configuration hits (a ``str``, ``""`` where free,
  e.g. ``"table"`` or a landmark's name): ``hits`` passes the names on, so that the planner knows
  which blocked edges an object that moves away may free (``lfd.planning.edgestore``);
* ``segment_fn(q1: (d,), q2: (d,)) -> bool`` (True = the straight segment collides).

Connection rule (Karaman & Frazzoli's k-nearest PRM*): every vertex added when the roadmap holds
``n`` vertices is joined to its ``k_PRM*(n) = ceil(k_scale * e * (1 + 1/d) * log n)`` nearest
neighbours (Euclidean, scipy ``cKDTree``); ``k`` grows with ``n``. ``add_vertices`` grows a roadmap
incrementally: new vertices are joined to their nearest among old and new vertices, old edges are
kept, nothing is rebuilt except the k-d tree (O(n log n), milliseconds at n = 10^4).

The roadmap holds structure only: vertices are collision-checked when added, edges are not.
A candidate configuration that hits something the collision callables name (a sensed object,
say) is set aside rather than forgotten: ``readmit(name)`` checks those that hit ``name`` again
once it has moved, and adds the free ones, so that a space an object blocked while the roadmap
was built is sampled again when it leaves (as a fresh roadmap would be).
Whether an edge is collision-free is edge state, owned with the edge costs by
``lfd.planning.edgestore.EdgeStore`` (checked lazily on the paths a search returns, invalidated near
objects that move). Edges are never removed, so edge ids stay valid for every cache.

Vertices live in a numpy array ``vertices: (n, d)``; edges in a ``networkx.Graph`` whose nodes are
the integer vertex ids ``0..n-1``, with the attribute ``eid``: ``0, 1, 2, ...`` in the order the
edges were added (``edge_array()[eid]`` are its ends).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import networkx as nx
import numpy as np
from scipy.spatial import cKDTree

__all__ = ["UNNAMED", "Roadmap", "RoadmapSettings", "ik_biased_samples", "k_prm_star", "mixed_samples"]

UNNAMED = "?"  # what ``Roadmap.hits`` says of a collision the callables report as a bare True


def k_prm_star(n: int, d: int, k_scale: float = 1.0) -> int:
    """Number of neighbours of k-nearest PRM* for a roadmap of ``n`` vertices in dimension ``d``.

    ``ceil(k_scale * e * (1 + 1/d) * log n)``, at least 1 and at most ``n - 1`` (0 when n < 2).
    ``k_scale >= 1`` keeps the asymptotic optimality guarantee.
    """
    if d < 1:
        raise ValueError(f"Expected d >= 1, got {d}")
    if n < 2:
        return 0
    k = math.ceil(k_scale * math.e * (1.0 + 1.0 / d) * math.log(n))
    return int(min(max(k, 1), n - 1))


@dataclass(frozen=True)
class RoadmapSettings:
    """k_scale: multiplier of k_PRM* (>= 1 for asymptotic optimality);
    max_sample_rounds: rounds of rejection sampling ``build`` tries before giving up."""
    k_scale: float = 1.0
    max_sample_rounds: int = 50

    def __post_init__(self):
        if not self.k_scale > 0:
            raise ValueError(f"Expected k_scale > 0, got {self.k_scale}")
        if self.max_sample_rounds < 1:
            raise ValueError(f"Expected max_sample_rounds >= 1, got {self.max_sample_rounds}")


class Roadmap:
    """A PRM* roadmap that grows incrementally.

    Parameters
    ----------
    d : dimension of the configuration space.
    collision_fn : ``q (d,) -> bool``, True when ``q`` is in collision.
    segment_fn : ``(q1 (d,), q2 (d,)) -> bool``, True when the segment collides.
    batch_collision_fn : optional ``Q (n, d) -> (n,) bool``; used instead of ``collision_fn`` for
        batches. Both may return names of what is hit instead of booleans (``hits``).
    settings : RoadmapSettings.
    movable : names of what may move (``set_movable``; None: anything the callables name).
    """

    def __init__(self, d: int, collision_fn: Callable, segment_fn: Callable, *,
                 batch_collision_fn: Callable | None = None,
                 settings: RoadmapSettings = RoadmapSettings(), movable=None):
        if int(d) != d or d < 1:
            raise ValueError(f"Expected d a positive integer, got {d!r}")
        self.d = int(d)
        self.collision_fn = collision_fn
        self.segment_fn = segment_fn
        self.batch_collision_fn = batch_collision_fn
        self.settings = settings
        self.graph = nx.Graph()
        self._buf = np.empty((0, self.d))
        self._n = 0
        self._tree: cKDTree | None = None
        self._ends = np.empty((0, 2), dtype=np.int64)  # (E, 2) vertex ids by edge id
        self._pending: list[tuple[int, int]] = []  # edges added since _ends was last extended
        self._aside = np.empty((0, self.d))  # (k, d) candidates that hit a named thing (``readmit``)
        self._aside_what = np.empty(0, dtype=str)  # (k,) what each hit
        self._movable: tuple[str, ...] | None = None  # names whose candidates are set aside (None: any)
        self.set_movable(movable)
        self.counters = {"vertex_checks": 0, "segment_checks": 0, "edges_removed": 0, "readmitted": 0}

    # ------------------------------------------------------------------ construction
    @classmethod
    def build(cls, sample_fn: Callable, n: int, collision_fn: Callable, segment_fn: Callable, *,
              biased_samples: np.ndarray | None = None, batch_collision_fn: Callable | None = None,
              settings: RoadmapSettings = RoadmapSettings(), movable=None) -> Roadmap:
        """Sample ``n`` collision-free vertices and connect them.

        ``biased_samples: (m, d)`` are candidate configurations (e.g. from ``mixed_samples`` or
        ``ik_biased_samples``); the free ones among the first ``n`` are used first, uniform samples
        from ``sample_fn`` fill the rest. Fewer than ``n`` vertices result only when rejection
        sampling fails ``settings.max_sample_rounds`` times in a row.
        """
        if n < 1:
            raise ValueError(f"Expected n >= 1, got {n}")
        first = np.asarray(sample_fn(1), dtype=float)
        if first.ndim != 2:
            raise ValueError(f"Expected sample_fn(n) to return shape (n, d), got {first.shape}")
        rm = cls(first.shape[1], collision_fn, segment_fn, batch_collision_fn=batch_collision_fn,
                 settings=settings, movable=movable)
        chunks, have = [], 0
        if biased_samples is not None:
            B = rm._check_Q(biased_samples, "biased_samples")[:n]
            B = B[rm.free_or_set_aside(B)]
            chunks.append(B)
            have = len(B)
        first = first[rm.free_or_set_aside(first)]
        chunks.append(first)
        have += len(first)
        for _ in range(settings.max_sample_rounds):
            if have >= n:
                break
            Q = rm._check_Q(sample_fn(n - have), "sample_fn(n)")
            Q = Q[rm.free_or_set_aside(Q)]
            chunks.append(Q)
            have += len(Q)
        Q = np.concatenate(chunks, axis=0)[:n] if chunks else np.empty((0, rm.d))
        rm.add_vertices(Q, check=False)
        return rm

    def _check_Q(self, Q, name: str) -> np.ndarray:
        Q = np.asarray(Q, dtype=float)
        if Q.ndim != 2 or Q.shape[1] != self.d:
            raise ValueError(f"Expected {name} with shape (n, {self.d}), got {Q.shape}")
        return Q

    def in_collision(self, Q: np.ndarray) -> np.ndarray:
        """Q: (n, d) -> (n,) bool, True where the configuration collides."""
        return self.hits(Q) != ""

    def hits(self, Q: np.ndarray) -> np.ndarray:
        """Q: (n, d) -> (n,) str: what each configuration hits, ``""`` where it is free; the
        collision callables' names when they give them, else ``UNNAMED``."""
        Q = _copy(self._check_Q(Q, "Q"))  # (the callables get a copy: their writes change nothing here)
        self.counters["vertex_checks"] += len(Q)
        if len(Q) == 0:
            return np.zeros(0, dtype=str)
        if self.batch_collision_fn is not None:
            out = _numpy(self.batch_collision_fn(Q))
            if out is None:
                raise ValueError("batch_collision_fn returned None: it must answer each configuration "
                                 "with a bool or the name of what it hits (a missing return?)")
            # (a list mixing names and False must not become the string "False")
            out = out if isinstance(out, np.ndarray) else np.asarray(out, dtype=object)
            if out.size != len(Q):  # (a scalar was numpy's 'cannot reshape')
                raise ValueError(f"batch_collision_fn must answer each of the {len(Q)} configurations, "
                                 f"shape ({len(Q)},); got shape {out.shape}")
            out = out.reshape(len(Q))
            if out.dtype.kind == "U":  # names already
                return out
            if out.dtype.kind == "O":
                return np.array([_name(x, "batch_collision_fn") for x in out.tolist()])
            if out.dtype.kind not in "biu" or not np.isin(out, (0, 1)).all():
                hint = " (a distance? compare it with a margin first)" if out.dtype.kind in "fiu" else ""
                raise ValueError(f"batch_collision_fn must answer with bools (or 0 and 1) or names, got "
                                 f"dtype {out.dtype}{hint}")
            return np.where(out.astype(bool), UNNAMED, "")
        return np.array([_name(self.collision_fn(q), "collision_fn") for q in Q])

    def set_movable(self, names) -> None:
        """The names of what may move (e.g. the sensed landmarks): only candidates that hit one
        of them are set aside from now on (None: anything named)."""
        self._movable = None if names is None else tuple(str(n) for n in names)

    def free_or_set_aside(self, Q: np.ndarray) -> np.ndarray:
        """``Q: (n, d) -> (n,) bool``, True where the configuration is free. Those that hit a
        named thing that may move (``set_movable``) are set aside for ``readmit``; the others
        are dropped (an unnamed obstacle, the robot itself, the joint limits: no move is told to
        free them)."""
        Q = self._check_Q(Q, "Q")
        what = self.hits(Q)
        named = (what != "") & (what != UNNAMED)
        if self._movable is not None:
            named &= np.isin(what, self._movable)
        if named.any():
            self._aside = np.concatenate([self._aside, Q[named]])
            self._aside_what = np.concatenate([self._aside_what, what[named]])
        return what == ""

    @property
    def n_set_aside(self) -> int:
        """Candidate configurations set aside because they hit a named thing."""
        return len(self._aside)

    def readmit(self, name: str, limit: int | None = None) -> np.ndarray:
        """Check again the configurations set aside for hitting ``name`` (which has moved): the
        free ones become vertices (at most ``limit``; the surplus is dropped), the rest are set
        aside again under what they hit now. Returns the new vertex ids ``(m,)``."""
        pick = self._aside_what == str(name)
        if not pick.any():
            return np.zeros(0, dtype=int)
        Q = self._aside[pick]
        self._aside, self._aside_what = self._aside[~pick], self._aside_what[~pick]
        Q = Q[self.free_or_set_aside(Q)]
        if limit is not None:
            Q = Q[:max(0, int(limit))]
        self.counters["readmitted"] += len(Q)
        return self.add_vertices(Q, check=False)

    def add_vertices(self, Q: np.ndarray, check: bool = True) -> np.ndarray:
        """Add configurations ``Q: (m, d)`` and connect each to its ``k_PRM*(n_total)`` nearest.

        Colliding configurations are left out when ``check`` (set aside, ``free_or_set_aside``).
        Returns the new vertex ids ``(m',)``. Existing vertices and edges are kept; only the k-d
        tree is rebuilt.
        """
        Q = self._check_Q(Q, "Q")
        if check and len(Q):
            Q = Q[self.free_or_set_aside(Q)]
        m = len(Q)
        if m == 0:
            return np.zeros(0, dtype=int)
        n0 = self._n
        if n0 + m > len(self._buf):  # amortized growth of the vertex buffer
            buf = np.empty((max(2 * len(self._buf), n0 + m), self.d))
            buf[:n0] = self._buf[:n0]
            self._buf = buf
        self._buf[n0:n0 + m] = Q
        self._n = n0 + m
        ids = np.arange(n0, n0 + m)
        self.graph.add_nodes_from(ids.tolist())
        self._tree = cKDTree(self.vertices)
        k = self.k()
        if k > 0:
            _, nbr = self._tree.query(Q, k=k + 1)
            nbr = nbr.reshape(m, k + 1)
            for i, row in zip(ids.tolist(), nbr.tolist()):
                for j in row:
                    if j != i and j < self._n and not self.graph.has_edge(i, j):
                        self._add_edge(i, j)
        return ids

    def add_edges(self, pairs) -> int:
        """Add edges ``pairs: (p, 2)`` of vertex ids besides the k-nearest ones (e.g. between
        consecutive configurations of a sampled task execution). Extra edges only add paths, so
        the PRM* guarantee is kept. Returns how many were new."""
        added = 0
        for i, j in np.asarray(pairs, dtype=int).reshape(-1, 2).tolist():
            if not (0 <= i < self._n and 0 <= j < self._n):
                raise ValueError(f"Expected vertex ids in [0, {self._n}), got ({i}, {j})")
            if i != j and not self.graph.has_edge(i, j):
                self._add_edge(i, j)
                added += 1
        return added

    def _add_edge(self, i: int, j: int) -> None:
        self.graph.add_edge(i, j, eid=self._n_edges)
        self._pending.append((i, j))

    def _segment_collides(self, q1, q2) -> bool:
        self.counters["segment_checks"] += 1
        return _name(self.segment_fn(_copy(q1), _copy(q2)), "segment_fn") != ""

    # ------------------------------------------------------------------ queries
    @property
    def n(self) -> int:
        """Number of vertices."""
        return self._n

    @property
    def vertices(self) -> np.ndarray:
        """(n, d) read-only view of the vertex configurations."""
        v = self._buf[:self._n]
        v.flags.writeable = False
        return v

    @property
    def _n_edges(self) -> int:
        return len(self._ends) + len(self._pending)

    @property
    def n_edges(self) -> int:
        """Number of edges (edge ids are ``0..n_edges-1``)."""
        return self._n_edges

    def edge_array(self) -> np.ndarray:
        """``(E, 2)`` read-only: the vertex ids of each edge, indexed by edge id."""
        if self._pending:
            self._ends = np.concatenate([self._ends, np.array(self._pending, dtype=np.int64)])
            self._pending = []
        e = self._ends.view()
        e.flags.writeable = False
        return e

    def k(self, n: int | None = None) -> int:
        """k_PRM* for ``n`` vertices (default: the current size)."""
        return k_prm_star(self._n if n is None else n, self.d, self.settings.k_scale)

    def nearest(self, q: np.ndarray, k: int) -> np.ndarray:
        """Ids ``(min(k, n),)`` of the vertices nearest to ``q: (d,)``, nearest first."""
        if self._tree is None or k < 1:
            return np.zeros(0, dtype=int)
        k = min(k, self._n)
        _, idx = self._tree.query(np.asarray(q, dtype=float).reshape(self.d), k=k)
        return np.atleast_1d(idx).astype(int)

    def segment_collides(self, q1: np.ndarray, q2: np.ndarray) -> bool:
        """Whether the straight segment ``q1-q2`` collides (``segment_fn``; not cached here)."""
        return self._segment_collides(np.asarray(q1, dtype=float), np.asarray(q2, dtype=float))


def _copy(a) -> np.ndarray:
    """A float copy of ``a``: what the user's callables receive, so that one that changes its
    argument in place (wrapping angles, say) cannot move the roadmap's vertices or the caller's
    start. (A read-only view would fail such a callable loudly, but torch warns on every
    ``torch.as_tensor`` of one, the usual first line of a check written in torch.)"""
    return np.array(a, dtype=float)


def _numpy(answer):
    """A torch tensor answer as a numpy array (a check written in torch), anything else as is."""
    if hasattr(answer, "detach") and hasattr(answer, "cpu"):
        return answer.detach().cpu().numpy()
    return answer


def _name(hit, what: str) -> str:
    """What the collision callable ``what``'s answer for one configuration (or segment) says is
    hit: its name, ``UNNAMED`` for a true answer, ``""`` for a false one (free). Anything else --
    ``None`` (a missing ``return``), a number that is not a bool or 0/1, several values -- is a
    ``ValueError``: read as "free" it would plan through obstacles."""
    if isinstance(hit, str):
        return hit
    if hit is None:
        raise ValueError(f"{what} returned None: it must answer True (collides), False (free) or the name "
                         "of what it hits (a missing return?)")
    a = np.asarray(_numpy(hit))
    if a.size == 1 and a.dtype.kind == "U":  # a 0-d name, np.where(hit, "box", "")
        return str(a.reshape(()).item())
    if a.size != 1 or a.dtype.kind not in "biu" or a.reshape(()).item() not in (0, 1):
        got = f"of shape {a.shape}" if a.size != 1 else f"{hit!r:.60}"
        raise ValueError(f"{what} must answer one configuration with a bool or a name, got {type(hit).__name__} {got}")
    return UNNAMED if a.reshape(()).item() else ""


def mixed_samples(sample_fn: Callable, n: int, biased_samples: np.ndarray, bias_fraction: float,
                  rng: np.random.Generator) -> np.ndarray:
    """``n`` configurations ``(n, d)``: ``round(bias_fraction * n)`` drawn without replacement from
    ``biased_samples: (m, d)`` (all of them when m is smaller), the rest from ``sample_fn``;
    shuffled.
    """
    if not 0.0 <= bias_fraction <= 1.0:
        raise ValueError(f"Expected bias_fraction in [0, 1], got {bias_fraction}")
    if n < 0:
        raise ValueError(f"Expected n >= 0, got {n}")
    B = np.asarray(biased_samples, dtype=float)
    if B.ndim != 2:
        raise ValueError(f"Expected biased_samples with shape (m, d), got {B.shape}")
    m = min(int(round(bias_fraction * n)), len(B))
    pick = B[rng.choice(len(B), size=m, replace=False)] if m else B[:0]
    U = np.asarray(sample_fn(n - m), dtype=float).reshape(n - m, B.shape[1])
    Q = np.concatenate([pick, U], axis=0)
    return Q[rng.permutation(n)]


def ik_biased_samples(targets, ik_fn: Callable) -> np.ndarray:
    """Configurations reaching task-space ``targets`` (e.g. the model's per-step means).

    ``ik_fn(targets) -> (Q: (m, d), ok: (m,) bool)``: any batched IK (lfd.robot.ik, with the tool
    offset and seeds chosen by the caller). Returns ``Q[ok]: (m', d)`` as a float numpy array.
    """
    Q, ok = ik_fn(targets)
    Q = np.asarray(Q.detach().cpu() if hasattr(Q, "detach") else Q, dtype=float)
    ok = np.asarray(ok.detach().cpu() if hasattr(ok, "detach") else ok, dtype=bool).reshape(-1)
    if Q.ndim != 2 or len(Q) != len(ok):
        raise ValueError("Expected ik_fn to return Q (m, d) and ok (m,), "
                         f"got {Q.shape}, {ok.shape}")
    return Q[ok]
