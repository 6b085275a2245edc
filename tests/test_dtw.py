"""DTW E-step against a brute-force enumeration of monotone alignments."""

import itertools

import numpy as np
import pytest
import torch

from lfd.learning.dtw import alignment_step_counts, dtw_align, min_samples, random_alignment, reference_alignments
from lfd.learning.priors import estimate_log_trans
from helpers import longest_stay


def _brute_force(cost, trans, offsets, dwell=None):
    S, T = cost.shape
    best, best_path = np.inf, None
    for incs in itertools.product(range(len(offsets)), repeat=S - 1):
        path = [0]
        total = cost[0, 0]
        for s, k in enumerate(incs, start=1):
            t = path[-1] + offsets[k]
            if t >= T:
                break
            total += trans[path[-1], k] + cost[s, t]
            path.append(t)
        else:
            if path[-1] == T - 1 and total < best and (dwell is None or longest_stay(path) <= dwell):
                best, best_path = total, path
    return best, best_path


@pytest.mark.parametrize("seed", range(4))
def test_dtw_equals_brute_force(seed):
    rng = np.random.default_rng(seed)
    T, offsets = 4, (0, 1, 2)
    lengths = [5, 7, 3, 6]
    cost = rng.normal(size=(len(lengths), 7, T)) ** 2
    trans = -2 * np.log(rng.dirichlet(np.ones(3), size=T))
    trans[T - 1, 1:] = np.inf
    trans[T - 2, 2] = np.inf
    align, values = dtw_align(torch.as_tensor(cost), lengths, torch.as_tensor(trans), offsets)
    for m, n in enumerate(lengths):
        best, path = _brute_force(cost[m, :n], trans, offsets)
        assert values[m].item() == pytest.approx(best, rel=1e-12)
        assert align[m].tolist() == path
        assert align[m][0] == 0 and align[m][-1] == T - 1


@pytest.mark.parametrize("seed", range(4))
def test_dwell_limited_dtw_equals_brute_force(seed):
    """With a dwell limit the best alignment is the brute force's best among those that stay at
    most ``dwell[m]`` consecutive samples on any step, and it differs from the unlimited one."""
    rng = np.random.default_rng(seed)
    T, offsets = 4, (0, 1, 2)
    lengths = [8, 9, 7, 9]
    dwell = [2, 3, 2, 4]
    cost = rng.normal(size=(len(lengths), 9, T)) ** 2
    cost[:, :, 1] *= 0.01  # step 1 is cheap: unlimited alignments stay there long
    trans = -2 * np.log(rng.dirichlet(np.ones(3), size=T))
    trans[T - 1, 1:] = np.inf
    trans[T - 2, 2] = np.inf
    free, _ = dtw_align(torch.as_tensor(cost), lengths, torch.as_tensor(trans), offsets)
    align, values = dtw_align(torch.as_tensor(cost), lengths, torch.as_tensor(trans), offsets, dwell)
    for m, n in enumerate(lengths):
        best, path = _brute_force(cost[m, :n], trans, offsets, dwell[m])
        assert values[m].item() == pytest.approx(best, rel=1e-12)
        assert align[m].tolist() == path
        assert longest_stay(path) <= dwell[m]
    assert any(longest_stay(a) > d for a, d in zip(free, dwell))  # the limit was binding


def test_dwell_limit_rejects_demonstrations_it_cannot_hold():
    cost = torch.zeros(1, 9, 4, dtype=torch.float64)
    with pytest.raises(ValueError, match="more samples than 4 steps"):
        dtw_align(cost, [9], torch.zeros(4, 3, dtype=torch.float64), dwell=[2])


def test_dtw_rejects_too_short_demonstrations():
    cost = torch.zeros(1, 3, 8, dtype=torch.float64)
    with pytest.raises(ValueError, match="fewer than 5 samples"):
        dtw_align(cost, [3], torch.zeros(8, 3, dtype=torch.float64))
    assert min_samples(24) == 13


@pytest.mark.parametrize("n", [13, 24, 200])
def test_random_alignment_is_monotone_and_complete(n):
    rng = np.random.default_rng(0)
    for _ in range(20):
        a = random_alignment(n, 24, rng)
        assert len(a) == n and a[0] == 0 and a[-1] == 23
        assert set(np.diff(a)) <= {0, 1, 2}


def test_min_samples_is_the_fewest_transitions_that_sum_to_the_task_exactly():
    """With a gap in the offsets the largest one does not fix the count: a 6-step task with
    (0, 1, 3) needs 3 transitions (3 + 1 + 1; two give 4 or 6), which ``max(offsets)`` put at 2.
    Checked against enumerating every sequence of transitions."""
    for T, offsets in [(6, (0, 1, 3)), (8, (0, 1, 3)), (11, (0, 1, 4)), (24, (0, 1, 2)), (9, (0, 1, 2, 3)),
                       (7, (0, 1))]:
        steps = [k for k in offsets if k > 0]
        fewest = next(n for n in range(1, T) if any(sum(c) == T - 1 for c in itertools.product(steps, repeat=n)))
        assert min_samples(T, offsets) == 1 + fewest, (T, offsets)
    with pytest.raises(ValueError, match="no sum of the offsets"):
        min_samples(6, (0, 2))


@pytest.mark.parametrize("T,offsets", [(8, (0, 1, 3)), (6, (0, 1, 3)), (11, (0, 1, 4)), (24, (0, 1, 2))])
def test_random_alignment_of_a_short_demonstration_uses_only_the_permitted_offsets(T, offsets):
    """Fewer samples than steps: each transition's step is one of the offsets, whatever they are
    (skips larger than 2 raised from numpy's sampling, or gave steps the offsets forbid)."""
    rng = np.random.default_rng(1)
    for n in range(min_samples(T, offsets), T):
        for _ in range(10):
            a = random_alignment(n, T, rng, offsets)
            assert len(a) == n and a[0] == 0 and a[-1] == T - 1 and set(np.diff(a)) <= set(offsets), (n, a)


def test_transition_estimate_keeps_a_floor_and_forbids_leaving():
    a = [np.array([0, 0, 0, 1, 2, 3, 3]), np.array([0, 1, 1, 2, 3])]
    counts = alignment_step_counts(a, 4)
    assert counts[0].tolist() == [2, 2, 0] and counts[3].tolist() == [1, 0, 0]
    p = estimate_log_trans(a, 4, (0, 1, 2), floor=0.01).exp().numpy()
    assert np.allclose(p.sum(1), 1)
    assert (p[:2] >= 0.0099).all()  # every permitted transition kept possible
    assert p[3].tolist() == [1.0, 0.0, 0.0] and p[2, 2] == 0.0


def _warped_series(rng, n, offset):
    """A 3-channel motion with a pulse at phase 0.6, time-warped at random and offset."""
    u = np.sort(rng.uniform(0, 1, n))
    u = (u - u[0]) / (u[-1] - u[0])  # (n,) phase of each sample
    u = u ** rng.uniform(0.7, 1.4)
    x = np.stack([np.sin(3 * u), np.exp(-((u - 0.6) / 0.05) ** 2), u ** 2], 1) + offset
    return u, x + rng.normal(0, 0.01, x.shape)


@pytest.mark.parametrize("offsets", [(0, 1, 2), (0, 1)])
def test_reference_alignments_put_one_phase_on_one_step(offsets):
    """Series of different lengths, warps and constant offsets (an arm elsewhere): the sample at
    a given phase gets the step the reference gives that phase, within one step, while
    independent random warps scatter it; the result is a permitted alignment."""
    rng = np.random.default_rng(1)
    T = 12
    phases, series = zip(*[_warped_series(rng, int(n), rng.normal(0, 2.0, 3))
                           for n in rng.integers(40, 160, 6)])
    ref = 2
    align = reference_alignments(series, T, ref, offsets=offsets)
    ref_step = np.interp(np.linspace(0, 1, 50), phases[ref], align[ref])  # step of each phase
    for u, a in zip(phases, align):
        assert a[0] == 0 and a[-1] == T - 1 and set(np.diff(a)) <= set(offsets)
        assert np.abs(np.interp(np.linspace(0, 1, 50), u, a) - ref_step).max() <= 1.01
    scattered = [random_alignment(len(u), T, rng, offsets) for u in phases]
    err = max(np.abs(np.interp(np.linspace(0, 1, 50), u, a) - ref_step).max() for u, a in zip(phases, scattered))
    assert err > 2


def test_reference_alignments_reject_bad_input():
    with pytest.raises(ValueError, match="ref must index"):
        reference_alignments([np.zeros((30, 2))], 8, ref=1)
    with pytest.raises(ValueError, match="cannot reach step"):
        reference_alignments([np.zeros((30, 2)), np.zeros((3, 2))], 8, ref=0)
    with pytest.raises(ValueError, match="one C"):
        reference_alignments([np.zeros((30, 2)), np.zeros((30, 3))], 8, ref=0)


def test_effective_demos_counts_the_demonstrations_a_step_rests_on():
    """Equal shares give M, one demonstration's private step gives 1 (each others' single
    passing observation barely counts), an unvisited step 0; occupancy sums to the lengths."""
    from lfd.learning.dtw import effective_demos, step_occupancy

    shared = [np.repeat(np.arange(4), 5) for _ in range(3)]  # 3 demos, 5 samples in each of 4 steps
    np.testing.assert_allclose(effective_demos(shared, 4), [3.0, 3.0, 3.0, 3.0])
    # demo 0 dwells 100 samples in step 1, the others pass it in one sample each
    private = [np.array([0] * 5 + [1] * 100 + [2] * 5), np.array([0] * 5 + [1] + [2] * 5),
               np.array([0] * 5 + [1] + [2] * 5)]
    eff = effective_demos(private, 4)
    np.testing.assert_allclose(eff[[0, 2]], [3.0, 3.0])
    assert eff[1] == pytest.approx(102 ** 2 / (100 ** 2 + 2)) and eff[1] < 1.05
    assert eff[3] == 0.0
    occ = step_occupancy(private, 4)
    assert occ.shape == (3, 4) and occ.sum(1).tolist() == [len(a) for a in private]
