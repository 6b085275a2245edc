"""Cleaning recorded readings before they are resampled: what real recorders write.

Real recordings are messy in a few known ways, each handled here and counted in a report:

* **Dropouts.** A tracker that loses a landmark, or a recorder whose tf lookup fails, writes a
  reading of NaN, an all-zero pose (position and quaternion 0) or a zero quaternion. Such a
  reading is missing, not a pose: it is left out and the landmark's other readings bridge it
  (by interpolation, as the recorder's own gaps), as long as no gap between two readings it
  keeps is longer than ``max_gap``. A joint reading with NaN is missing the same way.
  ``dropouts='refuse'`` refuses the recording at the first one instead.
* **Repeated and near-simultaneous stamps.** A recorder that stamps every row with its own clock
  repeats a slower tracker's latest reading until a new one arrives (the new one sometimes a few
  microseconds after the repeat). A run of identical readings is one reading, at the time it was
  first seen; two new readings stamped closer than ``MERGE_FRACTION`` of the tracker's period are
  one (the later value, the newer). The tracker's own rate is then counted from its distinct
  readings (``rate_hz``), and the speed check uses no interval shorter than its period.
* **Jitter.** A skeleton tracker's positions scatter by centimetres from frame to frame. It is
  measured (``jitter_mm``: the RMS distance of a reading from the chord of its two neighbours,
  scaled to the noise of one reading) and optionally smoothed (``smooth`` seconds: a
  Savitzky-Golay filter, ``scipy.signal.savgol_filter``, of degree 2 over that window, on the
  track resampled at the tracker's rate; orientations filtered as sign-aligned quaternions).
* **Outliers.** A reading farther from the median of its neighbours (two each side) than the
  landmark could move at ``MAX_LANDMARK_SPEED`` in two of the tracker's periods is a glitch (a
  swapped marker, a reflection): it is dropped and reported (``outliers='refuse'``: refused). A
  landmark still faster than that between the readings kept, or with more than
  ``MAX_OUTLIER_FRACTION`` of its readings outliers, is refused: those are no lone glitches.

The results are ``CleanTrack`` and ``CleanJoints``, with their ``TrackReport`` and ``JointReport``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import savgol_filter
from scipy.spatial.transform import Rotation

from lfd.io.raw import RecordingError
from lfd.learning.demo_checks import MAX_LANDMARK_DISTANCE, MAX_LANDMARK_SPEED

__all__ = ["DROPOUT_MODES", "MERGE_FRACTION", "OUTLIER_MODES", "QUAT_TOLERANCE", "CleanJoints", "CleanTrack",
           "JointReport", "TrackReport", "clean_joints", "clean_track"]

QUAT_TOLERANCE = 1e-3  # |norm - 1| allowed in a recorded quaternion
ZERO_QUATERNION = 0.5  # a quaternion shorter than this is a recorder's empty reading, not a rotation
MERGE_FRACTION = 0.25  # new readings closer than this fraction of the tracker's period are one reading
OUTLIER_NEIGHBOURS = 2  # readings each side in the running median an outlier is measured against
MAX_OUTLIER_FRACTION = 0.05  # more outliers than this fraction of the readings are no lone glitches
DROPOUT_MODES = ("bridge", "refuse")
OUTLIER_MODES = ("drop", "refuse")


@dataclass(frozen=True)
class TrackReport:
    """What was done to one landmark's readings. Times are on the recording's clock (s)."""

    readings: int  # as recorded
    dropouts: int  # missing readings bridged
    repeated: int  # repeats of the previous reading, merged into it
    merged: int  # new readings stamped closer than MERGE_FRACTION of the period to the next, merged
    outliers: int  # impossible jumps dropped
    kept: int  # readings the landmark's poses are interpolated from
    rate_hz: float | None  # the tracker's own rate (None: read once)
    jitter_mm: float | None  # RMS noise of one reading, before smoothing (None: too few readings)
    smoothed_s: float  # the smoothing window (0: not smoothed)
    longest_gap_s: float  # the longest time between two readings kept (a bridged dropout or the recorder's gap)
    dropout_times: tuple = ()
    outlier_times: tuple = ()
    outlier_where: tuple = ()  # the source's row / message of each outlier

    def as_dict(self) -> dict:
        return {"readings": self.readings, "dropouts": self.dropouts, "repeated": self.repeated,
                "merged": self.merged, "outliers": self.outliers, "kept": self.kept,
                "rate_hz": None if self.rate_hz is None else round(self.rate_hz, 2),
                "jitter_mm": None if self.jitter_mm is None else round(self.jitter_mm, 2),
                "smoothed_s": self.smoothed_s, "longest_gap_s": round(self.longest_gap_s, 4),
                "outlier_where": list(self.outlier_where)}

    def summary(self) -> str:
        """One line, the counts that are not zero."""
        parts = [f"{self.readings} readings"]
        if self.rate_hz is not None:
            parts.append(f"tracker {self.rate_hz:.1f} Hz")
        elif self.kept == 1:
            parts.append("held still")
        if self.dropouts:
            parts.append(f"{self.dropouts} dropouts bridged")
        if self.repeated or self.merged:
            parts.append(f"{self.repeated} repeated + {self.merged} near-simultaneous merged")
        if self.outliers:
            parts.append(f"{self.outliers} outlier(s) dropped at {list(self.outlier_where)}")
        if self.jitter_mm is not None:
            parts.append(f"jitter {self.jitter_mm:.1f} mm RMS")
        if self.smoothed_s:
            parts.append(f"smoothed over {self.smoothed_s:g} s")
        if self.rate_hz is not None:
            parts.append(f"longest gap {self.longest_gap_s:.3g} s")
        return ", ".join(parts)


@dataclass(frozen=True)
class CleanTrack:
    """A landmark's readings ready to interpolate: ``t (K,)`` strictly increasing, ``T_base_landmark
    (K, 4, 4)``; ``span``: the first and last time it was read (repeats included), for the check
    that it covers the demonstration."""

    t: np.ndarray
    T_base_landmark: np.ndarray
    span: tuple[float, float]
    report: TrackReport


@dataclass(frozen=True)
class JointReport:
    rows: int
    dropouts: int  # rows with a missing joint, bridged
    merged: int  # rows stamped at the same time as the next, merged into it
    longest_gap_s: float
    dropout_times: tuple = ()

    def as_dict(self) -> dict:
        return {"rows": self.rows, "dropouts": self.dropouts, "merged": self.merged,
                "longest_gap_s": round(self.longest_gap_s, 4)}


@dataclass(frozen=True)
class CleanJoints:
    t: np.ndarray  # (S,) strictly increasing
    q: np.ndarray  # (S, d)
    report: JointReport


def _refuse(where: str, what: str) -> RecordingError:
    return RecordingError(f"{where}: {what}")


def _decreasing(source: str, unit: str, t: np.ndarray, where: np.ndarray, what: str) -> None:
    d = np.diff(t)
    if (d < 0).any():
        i = int(np.flatnonzero(d < 0)[0])
        raise _refuse(source, f"{what}time goes back at {unit} {int(where[i + 1])} ({t[i + 1]:g} s after {t[i]:g} s)")


def _gap(source: str, t: np.ndarray, max_gap: float, what: str, bridged: int) -> float:
    """The longest interval of ``t``; refused over ``max_gap``."""
    if len(t) < 2:
        return 0.0
    d = np.diff(t)
    i = int(np.argmax(d))
    if d[i] > max_gap:
        note = f" ({bridged} missing readings bridged)" if bridged else ""
        raise _refuse(source, f"{what}a gap of {d[i]:.3g} s between {t[i]:g} s and {t[i + 1]:g} s{note}, longer "
                              f"than --max-gap {max_gap:g} s")
    return float(d[i])


def clean_joints(t: np.ndarray, q: np.ndarray, where: np.ndarray, source: str, unit: str, max_gap: float,
                 dropouts: str = "bridge") -> CleanJoints:
    """Joint readings ``t (S,)``, ``q (S, d)`` (a row with NaN: missing) with the missing rows left
    out (``dropouts='refuse'``: refused) and rows of one time stamp merged into the last of them."""
    missing = ~np.isfinite(q).all(axis=1)
    if missing.any() and dropouts == "refuse":
        raise _refuse(source, f"{unit} {int(where[np.argmax(missing)])}: a joint reading is missing (NaN or empty; "
                              "--dropouts bridge bridges it)")
    if missing.all():
        raise _refuse(source, "every joint reading is missing (NaN or empty)")
    _decreasing(source, unit, t, where, "")
    keep = ~missing
    tk, qk = t[keep], q[keep]
    same = np.append(np.diff(tk) == 0, False)  # (S',) stamped as the next: the next one is newer
    tk, qk = tk[~same], qk[~same]
    gap = _gap(source, tk, max_gap, "", int(missing.sum()))
    return CleanJoints(tk, qk, JointReport(rows=len(t), dropouts=int(missing.sum()), merged=int(same.sum()),
                                           longest_gap_s=gap, dropout_times=tuple(t[missing].tolist())))


def _dropout_mask(pose: np.ndarray) -> np.ndarray:
    """``(K,)`` True for a reading that is missing: NaN, a zero quaternion, or the all-zero
    position a failed lookup writes (when the landmark is read elsewhere too)."""
    finite = np.isfinite(pose).all(axis=1)
    norm = np.linalg.norm(np.where(finite[:, None], pose, 0.0)[:, 3:], axis=1)
    zero_pos = finite & (pose[:, :3] == 0).all(axis=1) if finite.any() else np.zeros(len(pose), bool)
    if zero_pos.all():  # a landmark read only at the origin is at the origin
        zero_pos[:] = False
    return ~finite | (norm < ZERO_QUATERNION) | zero_pos


def _runs(pose: np.ndarray) -> np.ndarray:
    """``(K,)`` True where a reading starts a run of identical readings (a new reading)."""
    new = np.ones(len(pose), bool)
    new[1:] = (pose[1:] != pose[:-1]).any(axis=1)
    return new


def _period(t: np.ndarray) -> float | None:
    """The tracker's period (s) from the times of its distinct readings: the mean interval, leaving
    out the intervals over three times the median (a pause of the tracker is not its rate)."""
    if len(t) < 3:
        return None
    d = np.diff(t)
    d = d[d > 0]
    if not len(d):
        return None
    typical = d[d <= 3 * np.median(d)]
    return float(typical.mean())


def _merge_close(t: np.ndarray, period: float) -> np.ndarray:
    """``(K,)`` True for a reading followed closer than ``MERGE_FRACTION * period`` by another
    (the later one, the newer, is kept)."""
    out = np.zeros(len(t), bool)
    out[:-1] = np.diff(t) < MERGE_FRACTION * period
    return out


def _outliers(t: np.ndarray, x: np.ndarray, period: float) -> np.ndarray:
    """``(K,)`` True for a position ``x (K, 3)`` farther from the median of its neighbours than
    ``MAX_LANDMARK_SPEED`` carries a landmark in two periods; two passes (a first outlier can hide
    a second next to it)."""
    bad = np.zeros(len(t), bool)
    limit = MAX_LANDMARK_SPEED * 2 * period
    for _ in range(2):
        idx = np.flatnonzero(~bad)
        if len(idx) < 3:
            break
        xs = x[idx]
        k = OUTLIER_NEIGHBOURS
        med = np.stack([np.median(xs[max(0, i - k):i + k + 1], axis=0) for i in range(len(idx))])
        far = np.linalg.norm(xs - med, axis=1) > limit
        if not far.any():
            break
        bad[idx[far]] = True
    return bad


def jitter_mm(t: np.ndarray, x: np.ndarray) -> float | None:
    """The RMS noise (mm) of one position reading ``x (K, 3)`` at times ``t (K,)``: each reading's
    distance from the chord of its two neighbours, divided by ``sqrt(1 + a^2 + b^2)`` (the chord's
    own noise, ``a + b = 1`` its weights), so that white noise of RMS ``s`` per reading gives ``s``;
    None with fewer than 5 readings. Smooth motion adds little: 3 mm at 3 m/s^2 and 30 Hz."""
    if len(t) < 5:
        return None
    t0, t1, t2 = t[:-2], t[1:-1], t[2:]
    a = (t2 - t1) / (t2 - t0)  # weight of the left neighbour
    b = 1.0 - a
    r = x[1:-1] - (a[:, None] * x[:-2] + b[:, None] * x[2:])  # (K - 2, 3)
    var = (r ** 2).sum(axis=1) / (1 + a ** 2 + b ** 2)
    return 1000.0 * math.sqrt(float(var.mean()))


def _smooth(t: np.ndarray, pose: np.ndarray, period: float, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The readings ``pose (K, 7)`` resampled every ``period`` s and filtered by Savitzky-Golay of
    degree 2 over ``window_s`` (an odd number of samples, at least 3): ``(t (G,), pose (G, 7))``."""
    grid = t[0] + np.arange(int(math.floor((t[-1] - t[0]) / period + 1e-9)) + 1) * period
    if grid[-1] < t[-1]:
        grid = np.append(grid, t[-1])
    quat = pose[:, 3:].copy()
    for i in range(1, len(quat)):  # one hemisphere: q and -q are one rotation
        if quat[i] @ quat[i - 1] < 0:
            quat[i] = -quat[i]
    cols = np.concatenate([pose[:, :3], quat], axis=1)
    res = np.stack([np.interp(grid, t, cols[:, j]) for j in range(7)], axis=1)
    window = max(3, int(round(window_s / period)) | 1)
    if window > len(grid):
        window = len(grid) if len(grid) % 2 else len(grid) - 1
    if window >= 3:
        res = savgol_filter(res, window, min(2, window - 1), axis=0, mode="interp")
    res[:, 3:] /= np.linalg.norm(res[:, 3:], axis=1, keepdims=True)
    return grid, res


def clean_track(name: str, t: np.ndarray, pose: np.ndarray, where: np.ndarray, source: str, unit: str,
                T_base_frame: np.ndarray, max_gap: float, dropouts: str = "bridge", outliers: str = "drop",
                smooth: float = 0.0) -> CleanTrack:
    """One landmark's readings ``t (K,)``, ``pose (K, 7)`` (x y z qx qy qz qw in the frame
    ``T_base_frame (4, 4)`` maps to the robot's base) cleaned as the module says.
    ``RecordingError`` naming ``source`` and the ``unit`` (row, message) for what cannot be."""
    what = f"landmark {name!r}: "
    if not np.isfinite(t).all():
        i = int(np.flatnonzero(~np.isfinite(t))[0])
        raise _refuse(source, f"{unit} {int(where[i])}: {what}the time is not a number")
    _decreasing(source, unit, t, where, what)
    drop = _dropout_mask(pose)
    if drop.any() and dropouts == "refuse":
        i = int(np.argmax(drop))
        raise _refuse(source, f"{unit} {int(where[i])}: {what}a dropout (NaN, all-zero pose or zero quaternion; "
                              "--dropouts bridge bridges it)")
    if drop.all():
        raise _refuse(source, f"{what}none of its {len(t)} readings is a pose (all are dropouts: NaN, zero "
                              "quaternions or all-zero poses)")
    norm = np.linalg.norm(pose[:, 3:], axis=1)
    bad = ~drop & (np.abs(norm - 1) > QUAT_TOLERANCE)
    if bad.any():
        i = int(np.argmax(bad))
        raise _refuse(source, f"{unit} {int(where[i])}: {what}quaternion (qx, qy, qz, qw) has norm {norm[i]:.4g}, not 1 "
                              f"(within {QUAT_TOLERANCE:g})")
    tv, pv, wv = t[~drop], pose[~drop], where[~drop]
    pv = np.concatenate([pv[:, :3], pv[:, 3:] / np.linalg.norm(pv[:, 3:], axis=1, keepdims=True)], axis=1)
    far = np.linalg.norm(pv[:, :3] @ T_base_frame[:3, :3].T + T_base_frame[:3, 3], axis=1)  # (K',) m from the base
    if far.max() > MAX_LANDMARK_DISTANCE:  # before the speed checks: another unit also "jumps"
        i = int(np.argmax(far))
        raise _refuse(source, f"{unit} {int(wv[i])}: {what}{far[i]:.4g} m from the robot's base, more than "
                              f"{MAX_LANDMARK_DISTANCE:g} m (millimetres given as metres, or another frame than the "
                              "base's?)")
    span = (float(tv[0]), float(tv[-1]))
    gap_all = _gap(source, tv, max_gap, what, int(drop.sum()))
    new = _runs(pv)
    tn, pn, wn = tv[new], pv[new], wv[new]
    period = _period(tn)
    merged = np.zeros(len(tn), bool)
    out = np.zeros(len(tn), bool)
    jitter = None
    if period is not None:
        merged = _merge_close(tn, period)
        tn, pn, wn = tn[~merged], pn[~merged], wn[~merged]
        period = _period(tn) or period
        out = _outliers(tn, pn[:, :3], period)
        if out.sum() > MAX_OUTLIER_FRACTION * len(out):
            raise _refuse(source, f"{what}{int(out.sum())} of its {len(out)} readings jump farther from their "
                                  f"neighbours than {MAX_LANDMARK_SPEED:g} m/s carries it: not lone glitches (a "
                                  "tracker that lost the landmark, or jitter of metres?)")
        if out.any() and outliers == "refuse":
            i = int(np.argmax(out))
            raise _refuse(source, f"{unit} {int(wn[i])}: {what}an impossible jump (farther from its neighbours than "
                                  f"{MAX_LANDMARK_SPEED:g} m/s carries it; --outliers drop drops it)")
        jitter = jitter_mm(tn[~out], pn[~out, :3])
    tk, pk = tn[~out], pn[~out]
    if len(tk) > 1:  # what is left must be one object's motion
        step = np.linalg.norm(np.diff(pk[:, :3], axis=0), axis=1)
        speed = step / np.maximum(np.diff(tk), period or 0.0)
        if speed.max() > MAX_LANDMARK_SPEED:
            i = int(np.argmax(speed))
            wk = wn[~out]
            raise _refuse(source, f"{what}moves {step[i]:.3g} m between {unit}s {int(wk[i])} and {int(wk[i + 1])} "
                                  f"({speed[i]:.3g} m/s over the time between them or the tracker's period, more than "
                                  f"{MAX_LANDMARK_SPEED:g} m/s) and stays there: "
                                  "another marker read as this landmark?")
    if smooth and period is not None and len(tk) >= 3:
        tk, pk = _smooth(tk, pk, period, smooth)
    T = np.tile(np.eye(4), (len(tk), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(pk[:, 3:]).as_matrix()
    T[:, :3, 3] = pk[:, :3]
    T = T_base_frame @ T
    report = TrackReport(readings=len(t), dropouts=int(drop.sum()), repeated=int((~new).sum()),
                         merged=int(merged.sum()), outliers=int(out.sum()), kept=len(tn) - int(out.sum()),
                         rate_hz=None if period is None else 1.0 / period, jitter_mm=jitter,
                         smoothed_s=float(smooth) if smooth and period is not None else 0.0,
                         longest_gap_s=gap_all, dropout_times=tuple(t[drop].tolist()),
                         outlier_times=tuple(tn[out].tolist()), outlier_where=tuple(int(w) for w in wn[out]))
    return CleanTrack(tk, T, span, report)
