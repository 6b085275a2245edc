"""Held-out validation (lfd.learning.validate, ``lfd-train --validate``): the scorer is the EM's
own aligned NLL, folds partition whole demonstrations, a well-posed set stays within the margin,
a model with far too many time steps is warned about, the command writes summary.json's block,
and folds that cannot be made are refused in one line."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from helpers import entry_point, run_cli
from lfd.errors import UserInputError
from lfd.learning.demos import save_demos
from lfd.learning.learn import FitConfig, fit
from lfd.learning.synthetic import make_synthetic
from lfd.learning.tasks import POWDER
from lfd.learning.validate import (
    OVERFIT_MARGIN,
    ValidationError,
    check_validation_set,
    cross_validate,
    fold_count,
    fold_indices,
    score,
)
from lfd.robot.kinematics import KinematicModel

T = 5


@pytest.fixture(scope="module")
def kin():
    return KinematicModel.from_spec()


def _synthetic(kin, n_demos, seed):
    """A well-posed set: 16 short demonstrations of a 5-step task (17-20 samples each), arm
    postures that differ only with the landmark's place. The joint block's 7 features need more
    than 7 + 2 demonstrations per step (Hotelling, lfd.learning.validate): with 6 of them
    (4 per fold) the held-out excess was 9.5-24 F over three seeds, with 16 (12 per fold)
    0.6-1.0 F."""
    ds, _ = make_synthetic(kin, n_demos=n_demos, time_steps=T, samples_per_step=(3, 4), Z=2, seed=seed,
                           task=POWDER, demo_spread=0.0)
    return ds


@pytest.fixture(scope="module")
def synth(kin):
    return _synthetic(kin, 16, seed=1)


@pytest.fixture(scope="module")
def fitted(kin, synth):
    cfg = FitConfig(time_steps=T, restarts=1, band=None)  # no band: the EM's E-step is the scorer's DTW
    return cfg, fit(synth, kin, cfg, workers=1)


def test_the_score_is_the_ems_own_aligned_nll(kin, synth, fitted):
    """On its training set the scorer's NLL per observation is the EM's E-step's (its DTW values
    over the observations) for the learned model, and that E-step with the priors added is the
    fit's own final loss."""
    from lfd.learning.em import EMFitter, FitData

    cfg, result = fitted
    m = result.model
    s = score(m, synth, max_dwell=cfg.max_dwell, kin=kin)
    data = FitData(synth, kin, torch.float64, torch.device("cpu"), cfg.features)
    fitter = EMFitter(data, cfg, torch.float64, torch.device("cpu"),
                      [synth.landmark_names.index(n) for n in m.landmark_names])
    align, values = fitter.e_step(m.tool, m.env, m.mu, m.sigma_inv, m.log_trans)
    assert s.n_observations == data.N == synth.n_observations
    assert s.nll_per_obs == pytest.approx(float(values.sum()) / data.N, rel=1e-12, abs=1e-12)
    assert all(np.array_equal(a, b) for a, b in zip(s.alignments, align))
    assert fitter.total_loss(m.tool, m.env, m.mu, m.sigma_inv, values) == pytest.approx(result.final_loss, rel=1e-10)
    assert s.nll_per_obs < result.final_loss  # the priors (the variance floor) are left out
    # the per-demonstration figures weigh into the set's, and the training Mahalanobis^2 is about F
    lengths = [d.n_samples for d in synth.demos]
    assert np.dot(s.demo_nll_per_obs, lengths) / sum(lengths) == pytest.approx(s.nll_per_obs, rel=1e-12)
    assert 0.7 * m.n_features < s.mahalanobis_per_obs <= m.n_features + 1e-9


def test_a_set_the_model_cannot_score_is_refused(kin, synth, fitted):
    cfg, result = fitted
    short = replace(synth, demos=(replace(synth.demos[0], q=synth.demos[0].q[:T - 1],
                                          name="short"), *synth.demos[1:]))
    with pytest.raises(ValidationError, match=r"\['short'\] have fewer than 5 samples"):
        score(result.model, short, kin=kin)
    renamed = replace(synth, landmark_names=("cup", "lm1"))
    with pytest.raises(ValidationError, match=r"needs landmark\(s\) \['bowl'\]"):
        score(result.model, renamed, kin=kin)
    slower = replace(synth, demos=tuple(replace(d, dt=0.2) for d in synth.demos), task=replace(POWDER, dt=0.2))
    with pytest.raises(ValidationError, match="sampled every 0.2 s, the model's steps every 0.1 s"):
        score(result.model, slower, kin=kin)
    with pytest.raises(ValidationError, match="landmarks"):
        check_validation_set(synth, renamed)
    with pytest.raises(ValidationError, match="same joint trajectory"):
        check_validation_set(synth, replace(synth, demos=synth.demos[:1]))


def test_folds_partition_whole_demonstrations_from_the_seed():
    parts = fold_indices(11, 5, seed=0)
    assert sorted(i for p in parts for i in p) == list(range(11))
    assert sorted(len(p) for p in parts) == [2, 2, 2, 2, 3]
    assert fold_indices(11, 5, seed=0) == parts and fold_indices(11, 5, seed=1) != parts
    assert sorted(fold_indices(4, "loo", seed=3)) == [(0,), (1,), (2,), (3,)]


@pytest.mark.parametrize("folds, n, fragment", [
    (7, 6, "7 folds of 6 demonstrations: each fold holds out whole demonstrations, so there can be at most 6"),
    (1, 6, "needs at least 2 folds"),
    (2, 3, "leave 1 demonstration(s) to learn from in a fold, fewer than the 2 a fit needs"),
    ("loo", 2, "leave 1 demonstration(s)"),
    ("five", 6, "folds must be a whole number >= 2 or 'loo'"),
    (True, 6, "folds must be a whole number"),
])
def test_folds_that_cannot_be_made_are_refused(folds, n, fragment):
    with pytest.raises(ValidationError) as info:
        fold_count(folds, n)
    assert isinstance(info.value, UserInputError) and fragment in str(info.value)


def test_cross_validate_refuses_bad_folds_before_fitting(kin, synth, monkeypatch):
    import lfd.learning.validate as validate

    def no_fit(*a, **k):
        raise AssertionError("fit was called")

    monkeypatch.setattr(validate, "fit", no_fit)
    with pytest.raises(ValidationError, match="at most 16 folds"):
        cross_validate(synth, kin, FitConfig(time_steps=T, restarts=1), folds=17)


def test_a_well_posed_set_is_within_the_margin(kin, synth):
    reports = []
    v = cross_validate(synth, kin, FitConfig(time_steps=T, restarts=1), folds=4, progress=reports.append, workers=1)
    F = v.n_features
    assert v.folds == 4 and [r.fold for r in reports] == [0, 1, 2, 3] and all(r.folds == 4 for r in reports)
    assert sorted(i for p in v.heldout_demos for i in p) == list(range(16))
    assert [r.heldout_names for r in reports] == [tuple(synth.demos[i].name for i in p) for p in v.heldout_demos]
    # every demonstration is held out once: the held-out mean is the folds' total over all observations
    total = sum(c.heldout.nll_per_obs * c.heldout.n_observations for c in v.fold_scores)
    assert v.heldout_nll_per_obs == pytest.approx(total / synth.n_observations, rel=1e-12)
    assert math.isfinite(v.train_nll_per_obs) and v.train_nll_per_obs < v.heldout_nll_per_obs
    assert v.heldout_nll_per_obs - v.train_nll_per_obs < 3 * F < OVERFIT_MARGIN * F, v.summary()  # measured 0.6 F
    assert v.warning is None and v.summary()["warning"] is None


def test_far_too_many_time_steps_are_warned_about(kin, synth):
    """T close to the shortest demonstration's length, 6 demonstrations: a fold's step rests on
    about 5 observations (4 demonstrations, 1-2 samples each), fewer than its 7 joint features,
    so its Gaussian is the variance floor around those observations. (With all 16, 12 per fold,
    the same T is 1.8 F above training: enough observations per step.)"""
    few = replace(synth, demos=synth.demos[:6])
    shortest = min(d.n_samples for d in few.demos)
    v = cross_validate(few, kin, FitConfig(time_steps=shortest - 2, restarts=1), folds=3, workers=1)
    assert v.heldout_nll_per_obs - v.train_nll_per_obs > 10 * OVERFIT_MARGIN * v.n_features, v.summary()
    assert v.warning is not None and "describe the training scenes" in v.warning


def test_train_writes_the_validation_block(kin, synth, tmp_path, capsys):
    demos, other = tmp_path / "demos", tmp_path / "other"
    save_demos(demos, synth)
    save_demos(other, _synthetic(kin, 2, seed=2))
    main, prog = entry_point("train.py")
    base = ["--task", "powder", "--demos", demos, "--restarts", "1", "--time-steps", T, "--workers", "1"]
    r = run_cli(main, prog, [*base, "--out", tmp_path / "plain", "--quiet"], capsys)
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "plain" / "summary.json").read_text())["validation"] is None
    assert "validation" not in r.stdout

    r = run_cli(main, prog, [*base, "--out", tmp_path / "out", "--validate", "4", "--validation-demos", other], capsys)
    assert r.returncode == 0, r.stderr
    block = json.loads((tmp_path / "out" / "summary.json").read_text())["validation"]
    assert block["folds"] == 4 and block["warning"] is None
    assert math.isfinite(block["train_nll_per_obs"]) and math.isfinite(block["heldout_nll_per_obs"])
    assert len(block["fold_heldout_nll_per_obs"]) == 4 and block["margin"] == OVERFIT_MARGIN * block["n_features"]
    assert block["validation_set"]["n_demos"] == 2 and math.isfinite(block["validation_set"]["nll_per_obs"])
    assert r.stdout.count("  fold ") == 4  # a progress line per fold
    assert "validation (4 folds): NLL per observation" in r.stdout
    assert f"validation set {other} (2 demonstrations)" in r.stdout


@pytest.mark.parametrize("extra, fragment", [
    (["--validate", "17"], "--validate 17: 17 folds of 16 demonstrations"),
    (["--validate", "1"], "--validate must be a number of folds (at least 2) or 'loo'"),
    (["--validate", "some"], "--validate must be a number of folds"),
])
def test_train_refuses_bad_folds_in_one_line(synth, tmp_path, capsys, extra, fragment):
    demos = tmp_path / "demos"
    save_demos(demos, synth)
    r = run_cli(*entry_point("train.py"), ["--task", "powder", "--demos", demos, "--restarts", "1", "--time-steps", T,
                                           "--out", tmp_path / "out", *extra], capsys)
    err = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(err) == 1 and fragment in err[0], r.stderr
    assert not (tmp_path / "out").exists()
