"""The EM fit: objective pieces against references, and recovery of a known model."""

import json
import math
import time
from dataclasses import replace

import numpy as np
import pytest
import torch

from helpers import longest_stay
from lfd.learning.dtw import min_samples
from lfd.learning.em import EMFitter, FitData
from lfd.learning.fitconfig import FLOOR_LIMITS, SolverSettings
from lfd.learning.learn import FitConfig, fit, initial_guesses
from lfd.learning.model import step_nll_tensor
from lfd.learning.synthetic import make_synthetic
from lfd.learning.tasks import POWDER
from lfd.robot.kinematics import KinematicModel

T_STEPS = 8


@pytest.fixture(scope="module")
def kin():
    return KinematicModel.from_spec()


@pytest.fixture(scope="module")
def synth(kin):
    torch.set_num_threads(1)
    return make_synthetic(kin, seed=3, std_scale=0.5, time_steps=T_STEPS, task=POWDER)


def _fitter(ds, kin, cfg, dtype=torch.float64):
    data = FitData(ds, kin, dtype, torch.device("cpu"), cfg.features)
    return data, EMFitter(data, cfg, dtype, torch.device("cpu"), list(range(len(ds.landmark_names))))


def test_config_options_are_validated():
    with pytest.raises(ValueError, match=r"FitConfig.tool must be one of learn, gripper, tip; got 'tipp'"):
        FitConfig(tool="tipp")
    with pytest.raises(ValueError, match=r"FitConfig.covariance must be one of full, block"):
        FitConfig(covariance="diag")
    with pytest.raises(ValueError, match="FitConfig.device"):
        FitConfig(device="tpu")
    with pytest.raises(ValueError, match=r"FitConfig.init must be one of reference, random, linear; got 'dtw'"):
        FitConfig(init="dtw")
    with pytest.raises(ValueError, match="FitConfig.band"):
        FitConfig(band=-1)
    with pytest.raises(ValueError, match="SolverSettings.tool_search"):
        FitConfig(solver=SolverSettings(tool_search=-0.1))
    for bad in (2.5, 0, True):  # 2.5 was searched as a 2x2x2 grid
        with pytest.raises(ValueError, match=r"SolverSettings.tool_grid must be a whole number >= 1"):
            SolverSettings(tool_grid=bad)
    with pytest.raises(ValueError, match="FitConfig.max_dwell must be at least 1"):
        FitConfig(max_dwell=0.5)
    for bad in (-1.0, 0.0, float("nan")):  # was a non-positive-definite Sigma and 'every restart failed'
        with pytest.raises(ValueError, match="FitConfig.floor_weight must be a positive number"):
            FitConfig(floor_weight=bad)
    assert FitConfig(floor_weight=3.0).floor_weight == 3.0
    for name, widest in FLOOR_LIMITS.items():  # past ~1e154 every restart failed in a Cholesky
        assert getattr(FitConfig(**{name: widest}), name) == widest
        for bad in (widest * 1.01, 1e308):
            with pytest.raises(ValueError, match=f"FitConfig.{name} must be at most {widest:.4g}, wider than"):
                FitConfig(**{name: bad})
    assert FitConfig(time_steps=8, offsets=(0, 1, 4)).offsets == (0, 1, 4)  # the largest: max(2, T // 2)
    with pytest.raises(ValueError, match=r"FitConfig.offsets: 5 is larger than the largest permitted.* = 4"):
        FitConfig(time_steps=8, offsets=(0, 1, 5))
    for T in (2, 3):  # the usual set fits the smallest models
        assert FitConfig(time_steps=T, offsets=(0, 1, 2)).offsets == (0, 1, 2)


@pytest.mark.parametrize("init", ["reference", "random", "linear"])
def test_dwell_limit_holds_in_every_start_and_in_the_fit(synth, kin, init):
    """Every restart's start and the fitted alignments keep each demonstration at most
    ``ceil(max_dwell * S_m / T)`` consecutive samples on a step, whatever the starts."""
    from lfd.learning.dtw import dwell_limits

    ds, _ = synth
    cfg = FitConfig(time_steps=T_STEPS, init=init, max_dwell=1.2, restarts=2, seed=1,
                    solver=SolverSettings(max_em_iters=4))
    lengths = [d.n_samples for d in ds.demos]
    limit = dwell_limits(lengths, T_STEPS, cfg.max_dwell)
    assert limit == [math.ceil(1.2 * n / T_STEPS) for n in lengths]

    guesses = initial_guesses(0, lengths, T_STEPS, len(ds.landmark_names), cfg, series=[d.q for d in ds.demos])
    for _ in range(3):
        align0, _, _ = next(guesses)
        assert all(longest_stay(a) <= d and a[0] == 0 and a[-1] == T_STEPS - 1 for a, d in zip(align0, limit))
    res = fit(ds, kin, cfg)
    assert all(longest_stay(a) <= d for a, d in zip(res.alignments, limit))
    free = fit(ds, kin, FitConfig(time_steps=T_STEPS, init=init, max_dwell=None, restarts=2, seed=1,
                                  solver=SolverSettings(max_em_iters=4)))
    assert any(longest_stay(a) > d for a, d in zip(free.alignments, limit))  # the limit was binding


@pytest.mark.parametrize("band", [0, 1, 3])
def test_band_keeps_the_e_step_near_the_start(synth, kin, band):
    """With ``band`` every EM alignment stays within that many steps of the restart's start
    (here the reference alignment), and the loss still does not increase."""
    ds, _ = synth
    cfg = FitConfig(time_steps=T_STEPS, band=band, solver=SolverSettings(max_em_iters=6))
    data, fitter = _fitter(ds, kin, cfg)
    align0, tool0, w0 = next(initial_guesses(0, data.lengths, T_STEPS, len(ds.landmark_names), cfg,
                                             series=[d.q for d in ds.demos]))
    state, hist = fitter.em(torch.as_tensor(tool0), torch.as_tensor(w0), align0, True, True)
    for a0, a in zip(align0, state[-1]):
        assert np.abs(a - a0).max() <= band
    assert all(b <= a + 1e-9 for a, b in zip(hist, hist[1:]))


def test_linear_init_with_band_0_keeps_the_uniform_warp(synth, kin):
    """init='linear' starts every restart from the uniform time warp; with band 0 the fit's
    alignment is that warp, every step rests on every demonstration (effective_demos = M up to
    the uneven split of S_m into T parts), and the fit still recovers the tool point."""
    from lfd.learning.dtw import linear_alignment

    ds, truth = synth
    cfg = FitConfig(time_steps=T_STEPS, init="linear", band=0, restarts=2, seed=0)
    lengths = [d.n_samples for d in ds.demos]
    guesses = initial_guesses(0, lengths, T_STEPS, len(ds.landmark_names), cfg)
    for _ in range(2):
        align0, _, _ = next(guesses)
        assert all(np.array_equal(a, linear_alignment(n, T_STEPS)) for a, n in zip(align0, lengths))
    res = fit(ds, kin, cfg)
    assert all(np.array_equal(a, linear_alignment(n, T_STEPS)) for a, n in zip(res.alignments, lengths))
    assert min(res.effective_demos) > 0.9 * len(ds.demos)
    assert np.linalg.norm(res.model.tool.numpy() - truth.tool) < 0.02


@pytest.mark.parametrize("covariance,feature_set", [("full", "paper"), ("block", "paper"), ("block", "attitude")])
def test_vectorized_loss_equals_loop_over_observations(synth, kin, covariance, feature_set):
    ds, truth = synth
    cfg = FitConfig(time_steps=T_STEPS, covariance=covariance, features=feature_set)
    data, fi = _fitter(ds, kin, cfg)
    t_idx = torch.as_tensor(np.concatenate(truth.alignments))
    tool = torch.tensor([0.01, 0.02, 0.1], dtype=torch.float64)
    w = torch.tensor([0.6, 0.2, 0.1, 0.05, 0.05], dtype=torch.float64)
    mu, si = fi.eta_from(tool, w, t_idx)
    got = fi.joint_loss(tool, w, mu, si, t_idx)
    # reference: one observation at a time, features from the paper's definition
    total = 0.0
    for n in range(data.N):
        m = int(data.demo[n])
        K_inv = sum(w[i] * torch.linalg.inv(torch.as_tensor(ds.demos[m].landmarks[i])) for i in range(5))
        p = K_inv @ data.T_world_ee[n] @ torch.cat([tool, torch.ones(1, dtype=torch.float64)])
        f = [data.q[n], p[:3]]
        if feature_set == "attitude":  # the gripper's x and y axes as directions
            f += [(K_inv[:3, :3] @ data.T_world_ee[n, :3, k]) for k in range(2)]
        f = torch.cat(f)[None]
        total += float(step_nll_tensor(f, mu, si)[0, t_idx[n]])
    floor = torch.tensor([cfg.floor_joint] * 7 + [cfg.floor_task] * 3 + [cfg.floor_attitude] * (len(fi.floor) - 10),
                         dtype=torch.float64)
    assert torch.equal(fi.floor, floor)
    total += float(fi.nu * ((si * floor) ** 2).sum())  # the variance-floor prior
    assert float(got) == pytest.approx(total, rel=1e-10)
    # profiled objective (eta in closed form) equals the joint objective at that eta
    assert float(fi.profiled(tool, w, t_idx)) == pytest.approx(float(got), rel=1e-10)
    if covariance == "block":
        assert torch.count_nonzero(si[:, 7:, :7]) == 0


@pytest.mark.parametrize("feature_set", ["paper", "attitude"])
def test_profiled_gradient_matches_finite_differences(synth, kin, feature_set):
    ds, truth = synth
    _, fi = _fitter(ds, kin, FitConfig(time_steps=T_STEPS, features=feature_set))
    t_idx = torch.as_tensor(np.concatenate(truth.alignments))
    tool = torch.tensor([0.01, 0.02, 0.1], dtype=torch.float64, requires_grad=True)
    w = torch.tensor([0.6, 0.2, 0.1, 0.05, 0.05], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: fi.profiled(a, b, t_idx) / 1000, (tool, w), atol=1e-6)


def test_m_step_from_true_alignment_recovers_the_model(synth, kin):
    ds, truth = synth
    _, fi = _fitter(ds, kin, FitConfig(time_steps=T_STEPS))
    t_idx = torch.as_tensor(np.concatenate(truth.alignments))
    w0 = torch.full((5,), 0.2, dtype=torch.float64)
    tool, w, mu, si = fi.m_step(torch.zeros(3, dtype=torch.float64), w0, t_idx, True, True)
    assert np.linalg.norm(tool.numpy() - truth.tool) < 0.005
    assert float(w[0]) > 0.95
    assert abs(float(w.sum()) - 1.0) < 1e-12
    assert np.abs(mu[:, 7:].numpy() - truth.means).max() < 0.005
    Sigma = torch.linalg.inv(si.transpose(1, 2) @ si)[:, 7:, 7:]
    ratio = np.sqrt(np.diagonal(Sigma.numpy(), axis1=1, axis2=2)) / truth.stds
    assert ratio.min() > 0.6 and ratio.max() < 1.5


def test_fit_recovers_tool_point_and_landmark(synth, kin):
    ds, truth = synth
    res = fit(ds, kin, FitConfig(time_steps=T_STEPS, restarts=3, seed=0))
    m = res.model
    assert np.linalg.norm(m.tool.numpy() - truth.tool) < 0.01
    assert res.env_before_pruning["bowl"] > 0.95
    assert res.kept_landmarks == ("bowl",) and m.landmark_names == ("bowl",)
    assert float(m.env.sum()) == pytest.approx(1.0, abs=1e-12)
    assert all(torch.isfinite(x).all() for x in (m.mu, m.sigma_inv, m.tool))
    assert len(res.restart_losses) == 3 and res.final_loss <= min(res.restart_losses) + 1e-9
    assert all(a[0] == 0 and a[-1] == T_STEPS - 1 for a in res.alignments)
    # the default permits no skip: every demonstration visits every step, one step at a time
    assert m.offsets == (0, 1)
    assert all(set(np.diff(a).tolist()) <= {0, 1} and set(a.tolist()) == set(range(T_STEPS)) for a in res.alignments)
    # the synthetic demonstrations share every step: no demonstration has steps of its own
    from lfd.learning.dtw import effective_demos
    np.testing.assert_allclose(res.effective_demos, effective_demos(res.alignments, T_STEPS))
    assert np.median(res.effective_demos) > len(ds.demos) / 3
    assert not any("rest on few demonstrations" in w for w in res.warnings)
    assert np.isfinite(m.log_trans.exp().numpy()).all() and (m.log_trans.exp() > 0).sum() == sum(T_STEPS - k for k in m.offsets)
    for hist in res.loss_history:  # EM never increases the objective
        assert all(b <= a + 1e-6 for a, b in zip(hist, hist[1:]))
    # deterministic for a seed
    again = fit(ds, kin, FitConfig(time_steps=T_STEPS, restarts=3, seed=0))
    assert torch.equal(again.model.mu, m.mu) and torch.equal(again.model.tool, m.tool)


def test_fixed_modes_and_float32(synth, kin):
    ds, _ = synth
    res = fit(ds, kin, FitConfig(time_steps=T_STEPS, restarts=1, tool="tip", env="bowl", dtype="float32"))
    m = res.model
    assert m.mu.dtype == torch.float32
    assert m.tool.tolist() == pytest.approx(list(POWDER.manual_tool_point))
    assert m.landmark_names == ("bowl",) and m.env.tolist() == [1.0]
    res = fit(ds, kin, FitConfig(time_steps=T_STEPS, restarts=1, tool="gripper"))
    assert res.model.tool.tolist() == [0.0, 0.0, 0.0]


def test_subsample_fits_every_kth_sample_at_k_times_dt(kin):
    # a dense set (6 samples per step): fitting with subsample=2 is fitting the thinned set, and
    # the model plans and executes at the thinned interval
    torch.set_num_threads(1)
    ds, truth = make_synthetic(kin, seed=5, std_scale=0.5, time_steps=T_STEPS, task=POWDER, samples_per_step=(6, 9))
    cfg = FitConfig(time_steps=T_STEPS, restarts=1, seed=0)
    a = fit(ds, kin, FitConfig(**{**cfg.__dict__, "subsample": 2}))
    b = fit(ds.subsample(2), kin, cfg)
    assert a.model.task.dt == pytest.approx(2 * ds.task.dt) and a.model.options["subsample"] == 2
    assert torch.equal(a.model.mu, b.model.mu) and torch.equal(a.model.tool, b.model.tool)
    assert [len(x) for x in a.alignments] == [(d.n_samples + 1) // 2 for d in ds.demos]
    assert np.linalg.norm(a.model.tool.numpy() - truth.tool) < 0.02
    with pytest.raises(ValueError, match="FitConfig.subsample"):
        FitConfig(subsample=0)
    need = min_samples(T_STEPS, cfg.offsets)  # 8 steps: 8 samples with (0, 1), 5 with (0, 1, 2)
    with pytest.raises(ValueError, match=rf"fewer than {need} samples after keeping 1 sample in 20 \(FitConfig.subsample\)"):
        fit(ds, kin, FitConfig(**{**cfg.__dict__, "subsample": 20}))


@pytest.mark.parametrize("init", ["reference", "random", "linear"])
def test_a_skip_of_three_fits_demonstrations_too_short_for_skips_of_two(kin, init):
    """Offsets (0, 1, 3) and demonstrations of 4-5 samples for 8 steps (reachable only with skips
    of 3): every start of every restart is an alignment the offsets permit. The random starts
    raised from numpy's sampling, the linear one started with skips of 2 and found no alignment."""
    torch.set_num_threads(1)
    ds, _ = make_synthetic(kin, seed=3, std_scale=0.5, time_steps=T_STEPS, task=POWDER, samples_per_step=(6, 7))
    res = fit(ds, kin, FitConfig(time_steps=T_STEPS, offsets=(0, 1, 3), restarts=2, init=init, subsample=13),
              workers=1)  # every 13th sample: 4-5 of each demonstration
    shortest = min(len(a) for a in res.alignments)
    assert min_samples(T_STEPS, (0, 1, 3)) <= shortest < min_samples(T_STEPS, (0, 1, 2))
    assert all(set(np.diff(a)) <= {0, 1, 3} and a[0] == 0 and a[-1] == T_STEPS - 1 for a in res.alignments)
    assert all(math.isfinite(x) for x in res.restart_losses)


def test_numpy_numbers_in_the_settings_are_stored_as_python_numbers_and_the_model_saves(kin, tmp_path):
    """A sweep over ``np.arange`` seeds: the fit ran, then ``save`` and the checkpoint raised
    (int64 is not JSON), leaving a model folder without its config.json. And a string for
    ``volume_prior`` ('false' is truthy) was taken as True."""
    torch.set_num_threads(1)
    ds, _ = make_synthetic(kin, seed=5, std_scale=0.5, time_steps=T_STEPS, task=POWDER, samples_per_step=(3, 4))
    cfg = FitConfig(time_steps=np.int64(T_STEPS), restarts=np.int64(1), seed=np.int64(3), floor_task=np.float32(1e-3),
                    solver=SolverSettings(max_em_iters=np.int32(5), tool_search=np.float32(0.2)))
    assert type(cfg.seed) is int and type(cfg.floor_task) is float and type(cfg.solver.max_em_iters) is int
    from lfd.learning.checkpoint import config_record
    json.dumps(config_record(cfg))  # what a checkpoint writes
    res = fit(ds, kin, cfg, workers=1)
    res.model.save(tmp_path / "m")
    assert json.loads((tmp_path / "m" / "config.json").read_text())["options"]["seed"] == 3
    with pytest.raises(TypeError, match="volume_prior must be True or False"):
        FitConfig(volume_prior="false")
    assert FitConfig(volume_prior=np.bool_(False)).volume_prior is False


def test_resume_with_subsample_equals_an_uninterrupted_fit(kin):
    # the checkpoint names the demonstrations as given (and the stride as an option), its state the
    # thinned samples: a fit resumed after its first restart ends where an uninterrupted one does
    torch.set_num_threads(1)
    ds, _ = make_synthetic(kin, seed=6, std_scale=0.5, time_steps=T_STEPS, task=POWDER, samples_per_step=(6, 9))
    cfg = FitConfig(time_steps=T_STEPS, restarts=2, seed=1, subsample=2)
    saved = []
    full = fit(ds, kin, cfg, on_restart=saved.append)
    assert saved[0].best_state["alignment"].numel() == ds.subsample(2).n_observations
    resumed = fit(ds, kin, cfg, resume=saved[0])
    assert resumed.resumed_restarts == 1 and resumed.restart_losses == pytest.approx(full.restart_losses)
    assert torch.equal(resumed.model.mu, full.model.mu) and torch.equal(resumed.model.tool, full.model.tool)
    from lfd.learning.checkpoint import CheckpointError
    with pytest.raises(CheckpointError, match="subsample"):
        fit(ds, kin, FitConfig(**{**cfg.__dict__, "subsample": 3}), resume=saved[0])


def test_non_finite_restart_is_dropped(synth, kin):
    ds, _ = synth
    calls = {"n": 0}

    def prior(tool, w):  # poisons the first restart only (no tool grid search: one call per start)
        calls["n"] += 1
        return tool.sum() * (math.nan if calls["n"] < 2 else 0.0)

    with pytest.warns(RuntimeWarning, match="restart 0 dropped"):
        res = fit(ds, kin, FitConfig(time_steps=T_STEPS, restarts=2, zeta_prior=prior, solver=SolverSettings(tool_search=0.0)),
                  workers=1)  # the poisoned call is the first one made: restart 0's, one restart at a time
    assert math.isnan(res.restart_losses[0]) and math.isfinite(res.final_loss)
    assert res.best_restart == 1 and any("restart 0 dropped" in w for w in res.warnings)
    with pytest.raises(ValueError, match="every one of the 1 restarts failed"):
        fit(ds, kin, FitConfig(time_steps=T_STEPS, restarts=1, zeta_prior=lambda t, w: t.sum() * math.nan))


def test_restarts_in_threads_give_the_fit_and_the_events_of_one_at_a_time(synth, kin):
    """Restarts run in parallel threads, restart 0 held up so that later ones finish first: the
    model, the losses, the per-iteration events and the checkpoints' progress, in the order of
    both together, are those of the restarts run one at a time (events of a restart that ran
    ahead are held back until the earlier ones and their ``on_restart`` are done)."""
    import threading
    import time

    ds, _ = synth
    lock, slept = threading.Lock(), []

    def hold_up_restart_0(tool, w):  # restart 0's first call: tool point 0, uniform weights
        if not bool(tool.abs().max() == 0) or not torch.allclose(w, torch.full_like(w, 1 / len(w))):
            return tool.new_zeros(())
        with lock:
            first = not slept
            slept.append(1)
        if first:
            time.sleep(1.0)
        return tool.new_zeros(())

    cfg = FitConfig(time_steps=T_STEPS, restarts=3, seed=2, zeta_prior=hold_up_restart_0)
    runs = {}
    for workers in (1, 3):
        calls = []
        slept.clear()
        res = fit(ds, kin, cfg, workers=workers,
                  callback=lambda ev: calls.append((ev["stage"], ev["restart"], ev["iteration"], ev["loss"])),
                  on_restart=lambda p: calls.append(("checkpoint", p.restarts_done, p.restart_losses)))
        runs[workers] = res, calls
    (a, calls_a), (b, calls_b) = runs[1], runs[3]
    assert slept and calls_b == calls_a
    assert [c[1] for c in calls_a if c[0] == "checkpoint"] == [1, 2, 3]
    assert [c[1] for c in calls_a if c[0] == "restart"] == sorted(c[1] for c in calls_a if c[0] == "restart")
    assert a.restart_losses == b.restart_losses and a.best_restart == b.best_restart
    for x, y in ((a.model.mu, b.model.mu), (a.model.sigma_inv, b.model.sigma_inv), (a.model.tool, b.model.tool),
                 (a.model.env, b.model.env)):
        assert torch.equal(x, y)
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="workers must be a whole number >= 1"):
            fit(ds, kin, cfg, workers=bad)


def test_an_error_in_a_restart_thread_ends_the_fit_and_stops_the_others(synth, kin, monkeypatch):
    """An exception other than a diverged restart ends the fit: it is raised as it is, the
    events of the restart that ran beside it are never delivered, and that restart stops at its
    next EM iteration instead of running to its end."""
    ds, _ = synth
    cfg = FitConfig(time_steps=T_STEPS, restarts=2, seed=0)
    whole = fit(ds, kin, cfg, workers=1).em_iterations[1]  # restart 1's iterations when it runs to its end
    assert whole >= 4
    e_steps = []
    e_step = EMFitter.e_step

    def counted(self, *args, **kw):
        e_steps.append(1)
        time.sleep(0.2)  # each E-step slow (the GIL released): restart 1 cannot run to its end in the
        return e_step(self, *args, **kw)  # moment restart 0's error takes to reach the fit (once it did)

    monkeypatch.setattr(EMFitter, "e_step", counted)
    seen = []

    def callback(ev):
        seen.append(ev["restart"])
        raise KeyError("the caller's callback failed")  # at restart 0's first iteration

    with pytest.raises(KeyError, match="the caller's callback failed"):
        fit(ds, kin, cfg, callback=callback, workers=2)
    assert seen == [0]  # restart 1's events were held, never delivered
    assert len(e_steps) < 1 + whole  # restart 1 stopped before its end


def test_tool_search_starts_lbfgs_from_the_best_grid_point(synth, kin):
    """The start is the grid point (or the current guess) of least profiled loss, nearer the
    truth than a far-off guess; tool_search=0 keeps the guess."""
    ds, truth = synth
    cfg = FitConfig(time_steps=T_STEPS, solver=SolverSettings(tool_search=0.2, tool_grid=3))
    data, fitter = _fitter(ds, kin, cfg)
    t_idx = torch.as_tensor(np.concatenate(truth.alignments))
    w = torch.zeros(5, dtype=torch.float64)
    w[truth.true_landmark] = 1.0
    far = torch.tensor([0.5, -0.5, 0.5], dtype=torch.float64)
    start = fitter.search_tool(far, w, t_idx)
    axis = torch.tensor([-0.2, 0.0, 0.2], dtype=torch.float64)
    cands = torch.cat([far[None], torch.cartesian_prod(axis, axis, axis)])
    losses = torch.stack([fitter.profiled(c, w, t_idx) for c in cands])
    assert torch.equal(start, cands[int(losses.argmin())])
    assert float(fitter.profiled(start, w, t_idx)) < float(fitter.profiled(far, w, t_idx))
    assert np.linalg.norm(start.numpy() - truth.tool) < np.linalg.norm(far.numpy() - truth.tool)
    off = FitConfig(time_steps=T_STEPS, solver=SolverSettings(tool_search=0.0))
    assert torch.equal(_fitter(ds, kin, off)[1].search_tool(far, w, t_idx), far)


def test_occupancy_note_warns_below_a_third():
    """The fit warns when the median step rests on under a third of the demonstrations."""
    from lfd.learning.learn import occupancy_note

    pour_like = np.array([1.2, 2.0, 3.3, 3.3, 6.0, 10.0])  # median 3.3 of 11
    assert "median 3.3 of 11" in occupancy_note(pour_like, 11)
    assert occupancy_note(np.full(6, 6.4), 11) is None  # the powder model's median
    assert occupancy_note(np.full(6, 1.0), 3) is None  # too few demonstrations to judge


@pytest.mark.parametrize("task", ["powder", "pour"])
def test_synthetic_set_takes_its_tasks_dt_and_loads_back(kin, tmp_path, task):
    """A synthetic set is sampled at its task's dt, so saved with its task.json it loads again
    (the loader refuses a task.json whose dt differs from the files')."""
    from lfd.learning.demos import load_demos, save_demos
    from lfd.learning.tasks import task_from_name

    spec = task_from_name(task)
    ds, _ = make_synthetic(kin, n_demos=2, time_steps=3, samples_per_step=(2, 3), seed=0, task=spec)
    assert {d.dt for d in ds.demos} == {spec.dt}
    save_demos(tmp_path, ds)
    back = load_demos(tmp_path, time_steps=3, kin=kin)
    assert back.task == spec and all(d.dt == spec.dt for d in back.demos)
    assert np.allclose(back.demos[0].q, ds.demos[0].q)


def test_synthetic_dt_is_checked(kin):
    with pytest.raises(ValueError, match="dt must be a positive number"):
        make_synthetic(kin, n_demos=2, time_steps=3, dt=0.0)


def test_a_landmark_tracked_while_it_moves_is_learned_and_its_first_pose_alone_is_not():
    """A handover-like set: the true landmark (a hand) travels 0.4 m during each demonstration and
    the task point follows it (``make_synthetic(landmark_motion=0.4)``, tracked poses ``(S, Z, 4,
    4)``). Learned with the tracked poses: the hand's weight >= 0.95 and the tool point within 2
    cm; learned from the same motions with each landmark frozen at its first pose (what the
    one-pose-per-demonstration format allowed): the tool point more than twice as far off (1.2
    against 0.4 cm with the dwell limit, 4.2 cm without) and the fit worse by several units of
    Eq. 3 per observation (-38.9 against -47.8)."""
    from dataclasses import replace
    kin = KinematicModel.from_spec()
    ds, truth = make_synthetic(kin, n_demos=8, time_steps=8, Z=3, seed=0, landmark_motion=0.4)
    assert ds.demos[0].landmarks.ndim == 4
    frozen = replace(ds, demos=tuple(replace(d, landmarks=d.landmarks[0]) for d in ds.demos))
    cfg = FitConfig(restarts=2, time_steps=8, seed=0)
    tracked, first = fit(ds, kin, cfg), fit(frozen, kin, cfg)
    err = {name: float(np.linalg.norm(r.model.tool.numpy() - truth.tool)) for name, r in (("tracked", tracked),
                                                                                          ("first", first))}
    assert tracked.env_before_pruning["bowl"] >= 0.95 and tracked.kept_landmarks == ("bowl",)
    assert err["tracked"] < 0.02
    assert err["first"] > 2 * err["tracked"] and first.final_loss > tracked.final_loss + 5.0


def _two_cups(ds, rng):
    """The set with its true landmark replaced by two landmarks that stand on either side of it
    (a random horizontal offset per demonstration): the task is relative to their midpoint, an
    environmental virtual landmark of weights 0.5 / 0.5."""
    from dataclasses import replace
    demos = []
    for d in ds.demos:
        lm = np.array(d.landmarks)  # (Z, 4, 4)
        off = np.r_[rng.uniform(-0.25, 0.25, 2), 0.0]
        a, b = lm[0].copy(), lm[0].copy()
        a[:3, 3] += off
        b[:3, 3] -= off
        demos.append(replace(d, landmarks=np.concatenate([a[None], lm[1:], b[None]])))
    names = ("cup_a", *ds.landmark_names[1:], "cup_b")
    return replace(ds, demos=tuple(demos), landmark_names=names, task=None)


def test_a_virtual_landmark_between_two_landmarks_is_learned_and_kept(synth, kin):
    """A hidden truth the paper's virtual landmark exists for: the task happens midway between
    two sensed landmarks. The fit finds weights near 0.5 / 0.5, keeps both through the
    pruning (repeated until every kept landmark weighs at least 5%) and drops the three others."""
    ds, truth = synth
    two = _two_cups(ds, np.random.default_rng(0))
    res = fit(two, kin, FitConfig(time_steps=T_STEPS, restarts=2, seed=0))
    assert set(res.kept_landmarks) == {"cup_a", "cup_b"}
    w = dict(zip(res.kept_landmarks, res.model.env.numpy()))
    assert abs(w["cup_a"] - 0.5) < 0.05 and abs(w["cup_b"] - 0.5) < 0.05
    assert np.linalg.norm(res.model.tool.numpy() - truth.tool) < 0.01


def test_pruning_is_repeated_until_no_kept_landmark_weighs_under_the_threshold(kin):
    """A refit after pruning moves the survivors' weights: here (a synthetic set, threshold 0.18%)
    lm4 weighs 0.181% before pruning, survives it, and falls to 0.165% in the refit. The paper's rule
    (the landmarks needed at execution are those of at least the threshold) holds for the final
    model: lm4 is pruned in a second refit, and every kept landmark weighs at least the threshold."""
    ds, _ = make_synthetic(kin, seed=3, std_scale=0.5, time_steps=T_STEPS, task=POWDER)
    thr = 0.0018
    res = fit(ds, kin, FitConfig(time_steps=T_STEPS, restarts=2, seed=0, prune_threshold=thr))
    assert res.env_before_pruning["lm4"] >= thr and "lm4" not in res.kept_landmarks
    assert len(res.loss_history) >= 2 + 2  # two restarts, then at least two refits
    assert "bowl" in res.kept_landmarks and np.abs(res.model.env.numpy()).min() >= thr


def test_final_gaussians_couple_the_tool_point_and_the_attitude_and_equal_each_steps_sample_covariance(synth, kin):
    """With the 'block' covariance and the attitude, zeta is learned with each group its own block
    but the model's Gaussians keep the tool point and the attitude in one block (how the tool
    point's place varies with the gripper's attitude): each step's covariance is the floored
    sample covariance of its observations, computed here one step at a time; the joints stay apart."""
    ds, _ = synth
    cfg = FitConfig(time_steps=T_STEPS, features="attitude", restarts=1, seed=0)
    res = fit(ds, kin, cfg)
    m = res.model
    data = FitData(ds, kin, torch.float64, torch.device("cpu"), cfg.features)
    fi = EMFitter(data, cfg, torch.float64, torch.device("cpu"), [ds.landmark_names.index(n) for n in m.landmark_names])
    f, _ = data.features(m.tool, m.env, fi.T_lm)  # (N, F)
    t_idx = np.concatenate(res.alignments)
    Sigma = torch.linalg.inv(m.sigma_inv.transpose(1, 2) @ m.sigma_inv)  # (T, F, F)
    d = 7
    for t in range(T_STEPS):
        x = f[torch.as_tensor(t_idx == t)]  # (n_t, F)
        n = len(x)
        c = x - x.mean(0)
        S = c.T @ c + fi.nu * torch.diag(fi.floor ** 2)
        ref = torch.zeros_like(S)
        ref[:d, :d] = S[:d, :d]
        ref[d:, d:] = S[d:, d:]
        ref /= cfg.logdet_scale * n
        assert torch.allclose(m.mu[t], x.mean(0), atol=1e-10)
        assert torch.allclose(Sigma[t], ref, rtol=1e-7, atol=1e-12), t
        assert torch.count_nonzero(m.sigma_inv[t, d:, :d]) == 0
    # the tool point and the attitude do vary together in these demonstrations
    cross = Sigma[:, d:d + 3, d + 3:].abs().amax()
    assert cross > 1e-3 * Sigma[:, d:d + 3, d:d + 3].diagonal(dim1=1, dim2=2).amax()
    # the paper's features have no attitude, and 'full' couples everything already: the EM's own
    # Gaussians are returned as they are
    for other in (FitConfig(time_steps=T_STEPS), FitConfig(time_steps=T_STEPS, features="attitude", covariance="full")):
        data_o = FitData(ds, kin, torch.float64, torch.device("cpu"), other.features)
        fo = EMFitter(data_o, other, torch.float64, torch.device("cpu"), list(range(len(ds.landmark_names))))
        mu_o, si_o = fo.final_eta(m.tool, None, m.mu, m.sigma_inv, res.alignments)
        assert mu_o is m.mu and si_o is m.sigma_inv


@pytest.mark.parametrize("feature_set,logdet_scale", [("paper", 1.0), ("attitude", 1.0), ("attitude", 2.0)])
def test_volume_prior_cancels_a_blend_of_rotations_for_every_transformed_vector(synth, kin, feature_set,
                                                                                 logdet_scale):
    """Two landmarks at the origin, the second turned 90 degrees about z, in every demonstration:
    weights (a, 1 - a) make ``A = a I + (1 - a) Rz^T``, which shrinks x and y by
    ``|det A| = a^2 + (1 - a)^2``. The profiled loss with the volume prior must not see that shrink
    (it equals the loss at the unblended frame, weights (1, 0)), whatever the number of vectors
    the features transform (one point with 'paper', a point and two axes with 'attitude') and the
    log-det scale; without the prior the blend would win by ``2 s k N log(1 / |det A|)``."""
    from dataclasses import replace
    ds, truth = synth
    Rz = np.eye(4)
    Rz[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]
    two = np.stack([np.eye(4), Rz])  # (2, 4, 4)
    ds2 = replace(ds, demos=tuple(replace(d, landmarks=two.copy()) for d in ds.demos),
                  landmark_names=("plain", "turned"), task=None)
    cfg = FitConfig(time_steps=T_STEPS, features=feature_set, logdet_scale=logdet_scale,
                    floor_joint=1e-9, floor_task=1e-9, floor_attitude=1e-9)
    _, fi = _fitter(ds2, kin, cfg)
    t_idx = torch.as_tensor(np.concatenate(truth.alignments))
    tool = torch.tensor([0.01, 0.02, 0.1], dtype=torch.float64)
    plain = float(fi.profiled(tool, torch.tensor([1.0, 0.0], dtype=torch.float64), t_idx))
    for a in (0.5, 0.8):
        blend = float(fi.profiled(tool, torch.tensor([a, 1.0 - a], dtype=torch.float64), t_idx))
        assert blend == pytest.approx(plain, abs=1e-6 * abs(plain)), (a, blend - plain)


def test_the_joint_m_step_leaves_a_step_without_observations_as_its_copy(synth, kin):
    """With skips permitted a step can be left without observations: ``eta_from`` copies the
    nearest step's Gaussian there, and the joint polish keeps that copy (the floor prior alone saw
    the step, and LBFGS sent its sigma_inv towards 0: a Gaussian that costs nothing anywhere)."""
    ds, truth = synth
    cfg = FitConfig(time_steps=T_STEPS, offsets=(0, 1, 2), solver=SolverSettings(m_step="joint", joint_max_iter=60))
    _, fi = _fitter(ds, kin, cfg)
    t_idx = torch.as_tensor(np.concatenate(truth.alignments))
    t_idx = torch.where(t_idx == 3, torch.full_like(t_idx, 2), t_idx)  # nobody at step 3
    tool = torch.tensor([0.01, 0.02, 0.1], dtype=torch.float64)
    w = torch.full((len(ds.landmark_names),), 1.0 / len(ds.landmark_names), dtype=torch.float64)
    mu, sigma_inv = fi.eta_from(tool, w, t_idx)
    assert torch.equal(sigma_inv[3], sigma_inv[2]) or torch.equal(sigma_inv[3], sigma_inv[4])
    _, _, mu2, si2 = fi.joint_polish(tool, w, mu, sigma_inv, t_idx, False, False)
    assert torch.equal(mu2[3], mu[3]) and torch.equal(si2[3], sigma_inv[3])
    assert not torch.equal(si2[2], sigma_inv[2])  # the observed steps were polished


def test_an_em_stopped_by_its_iteration_limit_returns_the_alignment_its_model_was_fitted_on(synth, kin):
    """Stopped before the alignments repeat, the fit's Gaussians, transitions and reported
    alignments must all come from one alignment (they mixed the last two E-steps' before)."""
    from lfd.learning.priors import estimate_log_trans
    ds, _ = synth
    cfg = FitConfig(time_steps=T_STEPS, restarts=1, seed=0, init="linear",
                    solver=SolverSettings(max_em_iters=1, em_tol=0.0))
    res = fit(ds, kin, cfg)
    m = res.model
    assert res.em_iterations[0] == 1
    # the last E-step did move samples: otherwise this test could not tell the two apart
    data, fi = _fitter(ds, kin, cfg)
    keep = [ds.landmark_names.index(n) for n in m.landmark_names]
    fi = EMFitter(data, cfg, torch.float64, torch.device("cpu"), keep)
    new_align, _ = fi.e_step(m.tool, m.env, m.mu, m.sigma_inv, m.log_trans)
    assert any(not np.array_equal(a, b) for a, b in zip(new_align, res.alignments))
    ref = estimate_log_trans(list(res.alignments), T_STEPS, cfg.offsets, cfg.trans_floor, torch.float64,
                             torch.device("cpu"))
    assert torch.equal(m.log_trans, ref)
    f, _ = data.features(m.tool, m.env, fi.T_lm)  # (N, F)
    t_idx = np.concatenate(res.alignments)
    for t in range(T_STEPS):
        assert torch.allclose(m.mu[t], f[torch.as_tensor(t_idx == t)].mean(0), atol=1e-9), t


def _demo0(ds, **changes):
    return replace(ds, demos=(replace(ds.demos[0], **changes), *ds.demos[1:]))


# (id, the DemoSet changed, the message): fit checks a set built in Python as load_demos checks files
FIT_INPUTS = [
    ("one-name-for-five-poses", lambda ds: replace(ds, landmark_names=ds.landmark_names[:1]),
     r"demonstration 'synth_00': key 'landmark_poses' must have shape \(1, 4, 4\)"),
    ("positions-not-poses", lambda ds: _demo0(ds, landmarks=ds.demos[0].landmarks[..., :3, 3]),
     r"demonstration 'synth_00': key 'landmark_poses' must be numeric of shape"),
    ("not-rigid", lambda ds: _demo0(ds, landmarks=ds.demos[0].landmarks * 2.0),
     r"demonstration 'synth_00': landmark 'bowl' pose is not a rigid transform"),
    ("dt-negative", lambda ds: replace(ds, demos=tuple(replace(d, dt=-0.1) for d in ds.demos)),
     r"demonstration 'synth_00': key 'dt' \(sampling interval, seconds\) must be positive"),
    ("dt-differs", lambda ds: _demo0(ds, dt=0.5),
     r"demonstration 'synth_01': sampling interval dt=0.1 differs from synth_00's dt=0.5"),
    ("nan-in-q", lambda ds: _demo0(ds, q=np.where(np.arange(ds.demos[0].n_samples)[:, None] == 2, np.nan,
                                                  ds.demos[0].q)),
     r"demonstration 'synth_00': key 'q' holds NaN or infinite values \(first at index \[2, 0\]\)"),
    ("task-dt", lambda ds: replace(ds, task=replace(ds.task, dt=0.02)),
     r"the DemoSet's task: dt=0.02 differs from the demonstrations' sampling interval dt=0.1"),
    ("joint-names", lambda ds: replace(ds, joint_names=tuple(f"j{i}" for i in range(7))),
     r"the DemoSet: unknown joint name\(s\) \['j0'"),
    ("no-demos", lambda ds: replace(ds, demos=()), r"the DemoSet: no demonstrations"),
]


@pytest.mark.parametrize("change,match", [f[1:] for f in FIT_INPUTS], ids=[f[0] for f in FIT_INPUTS])
def test_fit_checks_a_set_built_in_python_as_load_demos_checks_files(synth, kin, change, match):
    """Each was fitted without a word, or failed in numpy or the DTW, when the set never went
    through load_demos (built in Python, or lfd.io.recordings)."""
    from lfd.learning.demoset import DemoFormatError
    with pytest.raises(DemoFormatError, match=match):
        fit(change(synth[0]), kin, FitConfig(time_steps=T_STEPS, restarts=1), workers=1)


def test_fit_refuses_the_kinematics_of_another_robot_and_builds_the_sets_own_without_one(synth, kin):
    from lfd.learning.demoset import DemoFormatError
    from lfd.robot.robots import PANDA
    ds, _ = synth
    with pytest.raises(DemoFormatError, match=r"the DemoSet: the kinematic model \(kin\) is of joints "
                                              r"\['panda_joint1'.*not of the demonstrations' robot 'baxter_left'"):
        fit(ds, KinematicModel.from_spec(PANDA), FitConfig(time_steps=T_STEPS, restarts=1), workers=1)
    cfg = FitConfig(time_steps=T_STEPS, restarts=1, solver=SolverSettings(max_em_iters=2, tool_grid=2))
    own = fit(ds, None, cfg, workers=1)  # was an AttributeError in em.py
    assert own.final_loss == fit(ds, kin, cfg, workers=1).final_loss


def test_config_counts_are_whole_numbers_and_other_settings_numbers():
    for name, bad in (("time_steps", 4.0), ("restarts", 2.0), ("time_steps", "8"), ("restarts", True)):
        with pytest.raises(ValueError, match=rf"FitConfig.{name} must be a whole number >= \d, got {bad!r}"):
            FitConfig(**{name: bad})
    cfg = FitConfig(time_steps=np.int64(8), restarts=np.int32(2))
    assert (cfg.time_steps, cfg.restarts) == (8, 2) and type(cfg.time_steps) is int
    for name in ("prune_threshold", "floor_joint", "floor_task", "floor_attitude", "max_dwell", "floor_weight",
                 "logdet_scale", "tool_radius", "trans_floor"):  # Python's TypeErrors named no field
        with pytest.raises(ValueError, match=rf"FitConfig.{name} must be a number, got '0.1'"):
            FitConfig(**{name: "0.1"})
    for name in ("em_tol", "lbfgs_tol_grad", "tool_init_std", "tool_search"):
        with pytest.raises(ValueError, match=rf"SolverSettings.{name} must be a number, got '0.1'"):
            SolverSettings(**{name: "0.1"})


@pytest.mark.parametrize("which", ["zeta_prior", "eta_prior"])
def test_a_prior_that_returns_nan_fails_its_restart_by_name(synth, kin, which):
    """Was an IndexError inside torch's LBFGS line search."""
    from lfd.learning.fitconfig import FitError
    prior = lambda *args: torch.log(torch.zeros((), dtype=torch.float64)) * 0.0  # noqa: E731 (NaN)
    cfg = FitConfig(time_steps=T_STEPS, restarts=1, solver=SolverSettings(max_em_iters=3, tool_grid=2),
                    **{which: prior})
    with pytest.warns(RuntimeWarning), pytest.raises(
            FitError, match=r"every one of the 1 restarts failed: restart 0 dropped: the M-step's objective is nan "
                            r"at LBFGS evaluation \d+ \(a zeta_prior or eta_prior that returns NaN or inf\?\)"):
        fit(synth[0], kin, cfg, workers=1)
