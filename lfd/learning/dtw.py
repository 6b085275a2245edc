"""The E-step: dynamic time warping of demonstrations onto the model's time steps (Sec. IV-B).

Value recursion (costs in Eq. 3 units, 0-based steps here, 1-based in the paper)::

    l^0[t'] = c(0, t') if t' == 0 else inf            (alignments start at the first step)
    l^s[t'] = min_k (l^{s-1}[t' - o_k] + C_trans[t' - o_k, k]) + c(s, t')

and every alignment ends at the last step ``T - 1``. ``o_k`` are the permitted offsets
(``OFFSETS`` by default: stay, advance, or skip one step; the learner passes its own,
``FitConfig.offsets``) and ``C_trans = -2 log p(t + o_k | t)``. With a dwell limit
(``FitConfig.max_dwell``) the value is kept per step and samples stayed, ``l^s[t', d]``: a stay
moves ``d`` to ``d + 1`` up to the demonstration's limit, any other offset arrives with ``d = 0``.
The loop runs over samples only; time steps and demonstrations are vectorized (demonstrations
padded to one length, finished ones keep their value).
"""

from __future__ import annotations

import math

import numpy as np
import torch

OFFSETS = (0, 1, 2)  # the permitted step offsets unless told otherwise (a TaskModel's default too)

__all__ = [
    "OFFSETS",
    "alignment_step_counts",
    "dtw_align",
    "dwell_limits",
    "effective_demos",
    "linear_alignment",
    "min_samples",
    "project_alignments",
    "random_alignment",
    "reference_alignments",
    "step_occupancy",
]


def min_samples(time_steps: int, offsets=OFFSETS) -> int:
    """Fewest samples that can run from the first to the last step: one more than the fewest
    positive offsets that sum to ``time_steps - 1`` exactly (with ``(0, 1, 3)`` a 6-step task needs
    3 transitions, 3 + 1 + 1, not 2); ``ValueError`` when no sum of them does."""
    need = int(time_steps) - 1
    steps = sorted({int(k) for k in offsets if k > 0})
    fewest = [0] + [math.inf] * need  # fewest[v]: fewest positive offsets summing to v
    for v in range(1, need + 1):
        fewest[v] = 1 + min((fewest[v - k] for k in steps if k <= v), default=math.inf)
    if not math.isfinite(fewest[need]):
        raise ValueError(f"no sum of the offsets {tuple(offsets)} runs from step 0 to step {need}")
    return 1 + int(fewest[need])


def dwell_limits(lengths, time_steps: int, max_dwell: float | None) -> list[int] | None:
    """Most samples each demonstration may spend at one step: ``ceil(max_dwell * S_m / T)``,
    ``max_dwell`` times its mean per step (None: unlimited)."""
    if max_dwell is None:
        return None
    return [max(1, math.ceil(max_dwell * int(n) / time_steps)) for n in lengths]


def dtw_align(cost: torch.Tensor, lengths, trans_cost: torch.Tensor, offsets=OFFSETS, dwell=None):
    """Best alignment of each demonstration.

    Parameters
    ----------
    cost : (M, S_max, T) observation costs ``c(s, t)``; entries past a demonstration's
        length are ignored.
    lengths : (M,) number of samples of each demonstration.
    trans_cost : (T, K) cost of moving from step ``t`` by ``offsets[k]`` (``inf`` = forbidden).
    offsets : the permitted offsets, non-negative and distinct.
    dwell : None, or (M,) the most consecutive samples each demonstration may spend at one
        step (``dwell_limits``). The recursion then tracks how long the sample has stayed
        (states ``(t, d)``, ``d < dwell_m``): staying moves ``d`` to ``d + 1``, any other
        offset arrives with ``d = 0``.

    Returns
    -------
    alignments : list of M int64 numpy arrays ``(S_m,)``, 0-based steps, from 0 to T - 1.
    values : (M,) tensor, the total cost of each best alignment.

    Raises
    ------
    ValueError
        a demonstration too short to reach the last step, or too long to fit the dwell limit.
    """
    M, S, T = cost.shape
    lengths = [int(n) for n in lengths]
    offsets = tuple(int(k) for k in offsets)
    K, kmax = len(offsets), max(offsets)
    if trans_cost.shape != (T, K):
        raise ValueError(f"trans_cost must have shape ({T}, {K}), got {tuple(trans_cost.shape)}")
    too_short = [m for m, n in enumerate(lengths) if n < min_samples(T, offsets)]
    if too_short:
        raise ValueError(f"demonstration(s) {too_short} have fewer than {min_samples(T, offsets)} samples "
                         f"needed to reach time step {T} with offsets {offsets}")
    if dwell is not None:
        dwell = [int(x) for x in dwell]
        if len(dwell) != M or min(dwell) < 1 or 0 not in offsets:
            raise ValueError(f"dwell must hold a positive limit per demonstration ({M}) and offsets must "
                             f"include 0; got {dwell} and {offsets}")
        too_long = [m for m, (n, d) in enumerate(zip(lengths, dwell)) if n > d * T]
        if too_long:
            raise ValueError(f"demonstration(s) {too_long} have more samples than {T} steps of at most "
                             f"{[dwell[m] for m in too_long]} samples hold")
    dev, dt = cost.device, cost.dtype
    inf = torch.tensor(float("inf"), dtype=dt, device=dev)
    tprime = torch.arange(T, device=dev)
    off = torch.tensor(offsets, device=dev)
    src = tprime[:, None] - off[None, :]  # (T, K) predecessor step
    valid = src >= 0
    # shifted transition cost: arriving at t' via offset k costs trans_cost[t' - o_k, k]
    tc = torch.where(valid, trans_cost[src.clamp(min=0), torch.arange(K, device=dev)[None, :]], inf)
    D = 1 if dwell is None else max(dwell)
    if dwell is not None:  # a stay is the move (t, d) -> (t, d + 1), not an arrival at d = 0
        stay = offsets.index(0)
        stay_cost = trans_cost[:, stay]  # (T,)
        tc[:, stay] = inf
        over = torch.arange(D, device=dev)[None, :] >= torch.tensor(dwell, device=dev)[:, None]  # (M, D)
    gather = (src + kmax).clamp(min=0)  # index into l padded with kmax infs on the left

    lengths_t = torch.tensor(lengths, device=dev)
    value = torch.full((M, T, D), float("inf"), dtype=dt, device=dev)  # (M, T, D) by steps stayed
    value[:, 0, 0] = cost[:, 0, 0]
    pad = torch.full((M, kmax), float("inf"), dtype=dt, device=dev)
    pad_d = torch.zeros((M, kmax), dtype=torch.int64, device=dev)
    args = torch.zeros((S, M, T), dtype=torch.int8, device=dev)  # offset index of each arrival at d = 0
    came = torch.zeros((S, M, T), dtype=torch.int16, device=dev)  # and the d it left its step with
    for s in range(1, S):
        vmin, dmin = value.min(dim=2)  # (M, T)
        cand = torch.cat([pad, vmin], dim=1)[:, gather] + tc  # (M, T, K)
        best, arg = cand.min(dim=2)
        new = torch.empty_like(value)
        new[:, :, 0] = best + cost[:, s, :]
        if D > 1:
            new[:, :, 1:] = value[:, :, :-1] + (stay_cost + cost[:, s, :])[..., None]
        if dwell is not None:
            new = new.masked_fill(over[:, None, :], float("inf"))
        active = (lengths_t > s)[:, None, None]
        value = torch.where(active, new, value)
        args[s] = arg.to(torch.int8)
        if dwell is not None:  # without a limit every state has d = 0
            came[s] = torch.cat([pad_d, dmin], dim=1)[:, gather].gather(2, arg[..., None])[..., 0].to(torch.int16)
    values, d_end = value[:, T - 1].min(dim=1)
    if not torch.isfinite(values).all():
        bad = torch.nonzero(~torch.isfinite(values)).flatten().tolist()
        raise ValueError(f"no finite alignment for demonstration(s) {bad} (non-finite costs?)")

    args_np, came_np = args.cpu().numpy(), came.cpu().numpy()
    off_np = np.asarray(offsets)
    lens = np.asarray(lengths)
    t = np.full(M, T - 1, dtype=np.int64)
    d = d_end.cpu().numpy().astype(np.int64)
    out = np.zeros((M, S), dtype=np.int64)
    rows = np.arange(M)
    for s in range(S - 1, 0, -1):
        act = lens > s
        out[act, s] = t[act]
        k, back = args_np[s, rows, t], came_np[s, rows, t]
        arrived = act & (d == 0)
        t = np.where(arrived, t - off_np[k], t)
        d = np.where(arrived, back, np.where(act, d - 1, d))
    out[:, 0] = t
    if (t != 0).any() or (d != 0).any():  # cannot happen with finite values; kept as an internal check
        raise RuntimeError("DTW backtracking did not end at the first step")
    return [out[m, :lengths[m]].copy() for m in range(M)], values


def linear_alignment(n_samples: int, time_steps: int) -> np.ndarray:
    """The uniform time warp ``(n_samples,)``: sample s at step ``floor(s T / n)``, from 0 to T-1.

    With fewer samples than steps, it takes steps larger than 1 where needed and is not in general
    permitted by a set of offsets: ``project_alignments`` makes it so.
    """
    return np.minimum((np.arange(n_samples) * time_steps) // max(n_samples, 1), time_steps - 1) \
        if n_samples >= time_steps else np.round(np.linspace(0, time_steps - 1, n_samples)).astype(np.int64)


def random_alignment(n_samples: int, time_steps: int, rng: np.random.Generator,
                     offsets=OFFSETS) -> np.ndarray:
    """A random monotone alignment ``(n_samples,)`` from step 0 to ``time_steps - 1``.

    Steps advance at ``time_steps - 1`` of the ``n_samples - 1`` transitions, drawn without
    replacement with probabilities from a random smooth warp (so pace varies along the
    demonstration); offsets stay in ``{0, 1}`` and are hence permitted whenever 0 and 1 are.
    When there are fewer samples than steps, a random increasing warp is projected onto the
    alignments ``offsets`` permit (``project_alignments``; any offsets, not only 2).
    """
    n_trans = n_samples - 1
    need = time_steps - 1
    if n_trans >= need:
        knots = rng.gamma(2.0, size=6)
        rate = np.interp(np.linspace(0, 5, n_trans), np.arange(6), knots) + 0.2
        chosen = rng.choice(n_trans, size=need, replace=False, p=rate / rate.sum())
        inc = np.zeros(n_trans, dtype=np.int64)
        inc[chosen] = 1
        return np.concatenate([[0], np.cumsum(inc)])
    if n_samples < min_samples(time_steps, offsets):
        raise ValueError(f"{n_samples} samples cannot reach step {time_steps} with offsets {offsets}")
    warp = np.concatenate([[0.0], np.cumsum(rng.gamma(2.0, size=n_trans))])  # (n_samples,) increasing
    return project_alignments([warp * need / warp[-1]], time_steps, offsets)[0]


def reference_alignments(series, time_steps: int, ref: int, ref_alignment=None, offsets=OFFSETS,
                         max_points: int | None = None, dwell=None) -> list[np.ndarray]:
    """Consistent starting alignments: every demonstration warped onto one reference by DTW.

    Each series is centred on its own mean (a demonstration done with the arm elsewhere, e.g.
    for a farther bowl, still matches by the shape of its motion), scaled per channel by the
    spread of all centred samples, and aligned by
    ``dtw_align`` to ``R`` evenly spaced samples of the reference (squared distance, offsets
    ``(0, 1, 2)`` along the reference, no transition cost); a sample then takes the step the
    reference's alignment gives the matched reference sample. The result is finally projected
    onto the alignments permitted by ``offsets`` and ``dwell`` (``project_alignments``), so it
    always starts at step 0, ends at ``time_steps - 1`` and moves by permitted offsets only.

    Unlike ``random_alignment`` per demonstration, the same phase of the motion starts on the
    same step in every demonstration, so the first M-step sees step Gaussians of one phase each.

    Parameters
    ----------
    series : M arrays ``(S_m, C)`` (e.g. joint angles).
    time_steps : T.
    ref : index of the reference series.
    ref_alignment : ``(S_ref,)`` steps of the reference's samples (default: ``linear_alignment``).
    offsets : the permitted step offsets of the result.
    max_points : ``R`` at most (default ``4 T``); fewer when a series is too short to reach them.
    dwell : None or (M,) the most consecutive samples per step of each series (``dwell_limits``).

    Returns
    -------
    M int64 arrays ``(S_m,)``.
    """
    series = [np.asarray(x, dtype=float) for x in series]
    if not series or any(x.ndim != 2 for x in series) or len({x.shape[1] for x in series}) != 1:
        raise ValueError("series must be a non-empty list of (S_m, C) arrays with one C")
    if not 0 <= ref < len(series):
        raise ValueError(f"ref must index one of the {len(series)} series, got {ref}")
    lengths = [len(x) for x in series]
    need = min_samples(time_steps, offsets)
    if min(lengths) < need:
        raise ValueError(f"series of {min(lengths)} samples cannot reach step {time_steps} with offsets {offsets}")
    n_ref = lengths[ref]
    ref_alignment = linear_alignment(n_ref, time_steps) if ref_alignment is None else np.asarray(ref_alignment)
    if ref_alignment.shape != (n_ref,):
        raise ValueError(f"ref_alignment must have shape ({n_ref},), got {ref_alignment.shape}")
    centred = [x - x.mean(axis=0) for x in series]
    scale = np.maximum(np.concatenate(centred).std(axis=0), 1e-9)  # (C,)
    z = [x / scale for x in centred]
    R = min(max_points or 4 * time_steps, n_ref, 2 * (min(lengths) - 1) + 1)
    pick = np.round(np.linspace(0, n_ref - 1, max(R, 2))).astype(np.int64)  # (R,) reference samples
    z_ref = torch.as_tensor(z[ref][pick])
    cost = _padded([torch.cdist(torch.as_tensor(x), z_ref) ** 2 for x in z])  # (M, S_max, R)
    warp, _ = dtw_align(cost, lengths, torch.zeros((len(pick), 3), dtype=torch.float64), (0, 1, 2))
    want = [ref_alignment[pick[w]] for w in warp]  # (S_m,) desired steps
    return project_alignments(want, time_steps, offsets, dwell)


def project_alignments(want, time_steps: int, offsets=OFFSETS, dwell=None) -> list[np.ndarray]:
    """The permitted alignments closest to ``want`` (M arrays ``(S_m,)`` of steps, any values) in
    squared step error: from step 0 to ``time_steps - 1`` by ``offsets``, and at most ``dwell[m]``
    consecutive samples per step when ``dwell`` is given (see ``dtw_align``)."""
    t = np.arange(time_steps, dtype=float)
    proj = _padded([torch.as_tensor((np.asarray(w, dtype=float)[:, None] - t[None, :]) ** 2) for w in want])
    out, _ = dtw_align(proj, [len(w) for w in want],
                       torch.zeros((time_steps, len(offsets)), dtype=torch.float64), offsets, dwell)
    return out


def _padded(rows) -> torch.Tensor:
    """M tensors ``(S_m, K)`` -> one ``(M, S_max, K)`` float64 tensor, zeros past each end."""
    out = torch.zeros((len(rows), max(len(r) for r in rows), rows[0].shape[1]), dtype=torch.float64)
    for m, r in enumerate(rows):
        out[m, :len(r)] = r
    return out


def alignment_step_counts(alignments, time_steps: int, offsets=OFFSETS) -> np.ndarray:
    """``(T, K)`` counts of transitions from each step by each offset."""
    counts = np.zeros((time_steps, len(offsets)))
    index = {int(k): i for i, k in enumerate(offsets)}
    for a in alignments:
        d = np.diff(a)
        for k, i in index.items():
            np.add.at(counts[:, i], a[:-1][d == k], 1)
    return counts


def step_occupancy(alignments, time_steps: int) -> np.ndarray:
    """``(M, T)``: how many observations of each demonstration each step holds."""
    occ = np.zeros((len(alignments), time_steps), dtype=int)
    for m, a in enumerate(alignments):
        a = np.asarray(a, dtype=int)
        if len(a) and (a.min() < 0 or a.max() >= time_steps):
            raise ValueError(f"alignment {m} has steps outside 0..{time_steps - 1}")
        np.add.at(occ[m], a, 1)
    return occ


def effective_demos(alignments, time_steps: int) -> np.ndarray:
    """``(T,)``: how many demonstrations each step's Gaussian really rests on, the inverse Simpson
    index ``(sum_m n_mt)^2 / sum_m n_mt^2`` of the step's observations per demonstration ``n_mt``:
    M when every demonstration gives it as many observations, 1 when one demonstration gives
    all of them (0 for an empty step). Hard EM with long still phases (a pitcher held while it
    pours, 100+ samples at 50 Hz) can reach a higher likelihood by giving each demonstration a
    step of its own, with a Gaussian as narrow as that one demonstration; a planner then meets
    steps that describe one scene, not the task. This number shows it."""
    occ = step_occupancy(alignments, time_steps).astype(float)
    tot, sq = occ.sum(0), (occ ** 2).sum(0)
    return np.divide(tot ** 2, sq, out=np.zeros(time_steps), where=sq > 0)
