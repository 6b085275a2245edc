"""A buffer of the transforms of ``/tf`` and ``/tf_static``, kept per edge (parent -> child frame),
that chains a frame to a base frame through their common ancestor (any depth, either direction).
A frame is read at each stamp of a moving transform on its chain, with the chain's other moving
transforms interpolated there (positions linearly, orientations by slerp, as tf2's lookup does)
and each static one as last published.

Poses are ``(K, 7)`` rows ``x, y, z, qx, qy, qz, qw``, composed, inverted and interpolated with
``scipy.spatial.transform`` and NaN kept: a quaternion that is not unit keeps its norm (for the
cleaning to see), a zero or non-finite one (a dropout) gives NaN.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from lfd.io.raw import RawTrack, RecordingError

__all__ = ["TF_STATIC", "TF_TOPICS", "TfTree", "compose"]

TF_STATIC = "/tf_static"
TF_TOPICS = ("/tf", TF_STATIC)
_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


# ---------------------------------------------------------------------------------------------
# poses as (K, 7) rows x, y, z, qx, qy, qz, qw: composed, inverted and interpolated with NaN kept


def _rotations(q: np.ndarray) -> tuple[Rotation, np.ndarray, np.ndarray]:
    """The rotations of the quaternions ``q (K, 4)`` (the identity for a dropout), their norms and
    where they are dropouts (zero or not finite)."""
    norm = np.linalg.norm(q, axis=1)
    bad = ~(np.isfinite(q).all(axis=1) & (norm > 0))
    return Rotation.from_quat(np.where(bad[:, None], _IDENTITY, q)), norm, bad


def compose(T_a_b: np.ndarray, T_b_c: np.ndarray) -> np.ndarray:
    """``T_a_c (K, 7)``. The quaternions' norms multiply (a recorded quaternion that is not unit
    leaves its product not unit, a zero one a zero product); positions use the unit ones."""
    R_ab, n_ab, bad_ab = _rotations(T_a_b[:, 3:])
    R_bc, n_bc, _ = _rotations(T_b_c[:, 3:])
    p = T_a_b[:, :3] + R_ab.apply(T_b_c[:, :3])
    p[bad_ab] = np.nan
    with np.errstate(invalid="ignore"):  # (an infinite quaternion -> NaN)
        q = (R_ab * R_bc).as_quat() * (n_ab * n_bc)[:, None]
    return np.concatenate([p, q], axis=1)


def _inverse(T_a_b: np.ndarray) -> np.ndarray:
    """``T_b_a (K, 7)`` (the quaternion's inverse, of norm ``1 / |q|``)."""
    R, norm, bad = _rotations(T_a_b[:, 3:])
    R_inv = R.inv()
    with np.errstate(invalid="ignore", divide="ignore"):  # (a dropout, NaN below)
        out = np.concatenate([-R_inv.apply(T_a_b[:, :3]), R_inv.as_quat() / norm[:, None]], axis=1)
    out[bad] = np.nan
    return out


def _interpolate(tk: np.ndarray, pk: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Poses ``(M, 7)`` at the times ``t (M,)`` between readings ``pk (K, 7)`` at increasing ``tk (K,)``:
    positions linearly, orientations by slerp (the quaternions' norms linearly); NaN outside
    ``[tk[0], tk[-1]]``."""
    out = np.full((len(t), 7), np.nan)
    inside = (t >= tk[0]) & (t <= tk[-1])
    if len(tk) == 1:
        out[inside] = pk[0]
        return out
    ti = t[inside]
    i = np.clip(np.searchsorted(tk, ti, side="right") - 1, 0, len(tk) - 2)
    a = ((ti - tk[i]) / (tk[i + 1] - tk[i]))[:, None]
    rotations, norm, bad = _rotations(pk[:, 3:])
    q = Slerp(tk, rotations)(ti).as_quat()
    with np.errstate(invalid="ignore"):  # (a dropout, NaN below)
        # at a reading's stamp Slerp ends the segment before it, at either sign of it: the reading's kept
        q = np.where((a == 0) & ((q * pk[i, 3:]).sum(axis=1, keepdims=True) < 0), -q, q)
        q = q * ((1 - a) * norm[i, None] + a * norm[i + 1, None])
    q[bad[i] | bad[i + 1]] = np.nan
    out[inside] = np.concatenate([(1 - a) * pk[i, :3] + a * pk[i + 1, :3], q], axis=1)
    return out


# ---------------------------------------------------------------------------------------------
# the tree


@dataclass(frozen=True)
class _Edge:
    """One tf transform ``T_parent_child`` over time: ``t (K,)`` increasing, ``pose (K, 7)``,
    ``where (K,)`` message numbers on ``topic``; a static one holds its last reading (``K = 1``)."""

    parent: str
    t: np.ndarray
    pose: np.ndarray
    where: np.ndarray
    static: bool
    topic: str

    def at(self, t: np.ndarray) -> np.ndarray:
        return np.tile(self.pose[-1], (len(t), 1)) if self.static else _interpolate(self.t, self.pose, t)


class TfTree:
    """The transforms of ``/tf`` and ``/tf_static`` by child frame, and chains between frames.

    ``readings``: per tf topic, its readings in the bag's order as ``(t (K,), where (K,), data)``:
    times (s), message numbers and one ``(parent, child, pose (7,))`` per transform. ``bag``
    names the bag in the ``RecordingError`` of a tree that cannot be used.
    """

    def __init__(self, bag: Path, readings: Mapping[str, tuple[np.ndarray, Sequence[int], Sequence[tuple]]]):
        self.bag = bag
        rows: dict[str, list] = {}
        for topic, (times, wheres, data) in readings.items():
            for t, where, (parent, child, pose) in zip(times, wheres, data):
                rows.setdefault(child, []).append((t, where, parent, pose, topic))
        self.edges = {child: self._edge(child, r) for child, r in rows.items()}

    def _edge(self, child: str, rows: list) -> _Edge:
        parents = sorted({r[2] for r in rows})
        if len(parents) > 1:
            raise RecordingError(f"{self.bag}: tf frame {child!r} has more than one parent ({', '.join(parents)}); "
                                 "a tf tree gives each frame one")
        static = all(r[4] == TF_STATIC for r in rows)
        if static:
            rows = rows[-1:]  # a static transform is timeless: the last one published stands
        order = np.argsort([r[0] for r in rows], kind="stable")
        t = np.array([rows[i][0] for i in order])
        keep = np.append(t[1:] != t[:-1], True)  # one reading per stamp: the last one received
        sel = order[keep]
        return _Edge(parents[0], t[keep], np.array([rows[i][3] for i in sel], dtype=float).reshape(-1, 7),
                     np.array([rows[i][1] for i in sel], dtype=np.int64), static, rows[sel[0]][4])

    def _up(self, frame: str) -> list[str]:
        """``frame`` and its ancestors up to its tree's root."""
        path = [frame]
        while path[-1] in self.edges:
            parent = self.edges[path[-1]].parent
            if parent in path:
                raise RecordingError(f"{self.bag}: the tf tree has a loop through frames {path[path.index(parent):]}")
            path.append(parent)
        return path

    def frames(self) -> list[str]:
        return sorted({*self.edges, *(e.parent for e in self.edges.values())})

    def trees(self) -> str:
        """The frames, grouped by the tree they belong to, for a message."""
        roots: dict[str, list[str]] = {}
        for f in self.frames():
            roots.setdefault(self._up(f)[-1], []).append(f)
        return "; ".join(f"[{', '.join(fs)}]" for fs in roots.values()) or "no frames"

    def chain(self, frame: str, base: str, what: str) -> list[tuple[str, bool]]:
        """The edges from ``base`` to ``frame``, each as ``(child frame, inverted)``, in order:
        ``T_base_frame`` is their product. ``RecordingError`` when they are not connected."""
        if base not in self.frames():
            raise RecordingError(f"{self.bag}: the base frame {base!r} is not in /tf or /tf_static, so {what} "
                                 f"{frame!r} cannot be chained to it (the tf trees: {self.trees()})")
        up_frame, up_base = self._up(frame), self._up(base)
        common = next((f for f in up_frame if f in up_base), None)
        if common is None:
            raise RecordingError(f"{self.bag}: {what} {frame!r} is not connected to the base frame {base!r} "
                                 f"through /tf and /tf_static (the tf trees: {self.trees()})")
        down = up_frame[:up_frame.index(common)]
        return [(c, True) for c in up_base[:up_base.index(common)]] + [(c, False) for c in reversed(down)]

    def poses(self, chain: Sequence[tuple[str, bool]], t: np.ndarray) -> np.ndarray:
        """``T_base_frame (len(t), 7)`` along ``chain`` at the times ``t`` (NaN outside a moving
        transform's readings)."""
        out = np.tile([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], (len(t), 1))
        for child, inverted in chain:
            T = self.edges[child].at(t)
            out = compose(out, _inverse(T) if inverted else T)
        return out

    def track(self, chain: Sequence[tuple[str, bool]]) -> RawTrack:
        """The readings of a frame along ``chain``: at every stamp of its moving transforms while
        all of them have readings around it; once (at the latest stamp) when all are static."""
        edges = [self.edges[c] for c, _ in chain]
        moving = [e for e in edges if not e.static]
        if not moving:
            last = max(edges, key=lambda e: e.t[-1])
            return RawTrack(t=last.t[-1:], pose=self.poses(chain, last.t[-1:]), where=last.where[-1:])
        t = np.concatenate([e.t for e in moving])
        where = np.concatenate([e.where for e in moving])
        order = np.argsort(t, kind="stable")
        t, where = t[order], where[order]
        first = np.append(True, t[1:] != t[:-1])
        inside = (t >= max(e.t[0] for e in moving)) & (t <= min(e.t[-1] for e in moving))
        t, where = t[first & inside], where[first & inside]
        return RawTrack(t=t, pose=self.poses(chain, t), where=where)
