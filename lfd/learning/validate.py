"""Held-out validation of a learned task model: how well it describes demonstrations it never saw.

``score(model, demoset)`` aligns every demonstration to a ``TaskModel`` with the model's own DTW
(``lfd.learning.dtw.dtw_align`` over the model's step costs ``lfd.learning.model.step_nll_tensor``
and transition costs ``TaskModel.trans_cost``, within its ``offsets`` and the fit's dwell limit,
as the EM's E-step aligns) and returns the negative log-likelihood per observation of the best
alignment, in Eq. 3 units (``lfd.learning.model``: ``s log|Sigma_t| + |sigma_inv_t (f - mu_t)|^2``
per observation plus ``-2 log p(t'|t)`` per transition, i.e. twice the negative log-likelihood
less ``F log 2 pi`` per observation). The priors are left out (the variance floor, the volume
prior, the tool-radius bound), so the figure of the training set and that of a held-out set
are the same quantity. The alignment is the model's alone: the fit's Sakoe-Chiba band
(``FitConfig.band``) ties each demonstration to its restart's starting alignment, which a
held-out demonstration does not have, so on its training set the score is at most the fit's
(banded) E-step figure, and equal to it with ``band=None``.

``cross_validate(demoset, kin, config, folds=K)`` splits the demonstrations (whole ones, never
samples) into K folds (``'loo'``: one per demonstration), deterministically from
``config.seed``; for each fold it fits a model on the other demonstrations with the same
``FitConfig`` (``lfd.learning.learn.fit``) and scores it on its training part and on the
held-out fold. ``validation``: a separate set scored by the model learned from all the
demonstrations.

The warning (``OVERFIT_MARGIN``). Under a correct Gaussian model an observation's squared
Mahalanobis distance to its step is chi-square with F degrees of freedom (F the features):
mean F on the training set and on any other (the fit's covariances make the training mean F
less the variance floor's share: 9.8-9.96 of F = 10 measured on the powder). Both sets are
scored with the same log-determinants, so the held-out NLL per observation exceeds the training
one by about the held-out mean Mahalanobis^2 less F. Estimated from n demonstrations, a covariance
block of p features fits its training draws better than new ones by ``p (p + 3) / (n - p - 2)``
in expectation (Hotelling's predictive T^2), without bound once ``n <= p + 2``: the powder's 7
joints from the 8-9 demonstrations of a fold are there. So the margin is not a small multiple
of F but a distance: the warning is given when the held-out NLL per observation is more than
``OVERFIT_MARGIN * F = (OVERFIT_SD^2 - 1) F`` above the training figure, i.e. when held-out
observations lie further than ``OVERFIT_SD`` = 4 standard deviations from their steps, root mean
square over their features (a mean Mahalanobis^2 of 16 F), where a correct Gaussian puts a
feature 4 sd off once in 16,000 draws: the per-step Gaussians then describe the training scenes,
not the task (too many time steps for the demonstrations, variance floors too low, too few
demonstrations). Measured (docs/DESIGN.md, *Held-out validation*): the powder set's 5 folds at
T = 24 are 8.6 F above training (3.1 sd), T = 100 (its shortest demonstration has 110
samples) 33 F (5.8 sd).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from torch.nn.utils.rnn import pad_sequence

from lfd.errors import UserInputError
from lfd.learning.demo_checks import check_demoset, same_interval, unusable_demos
from lfd.learning.demoset import DemoSet
from lfd.learning.dtw import dtw_align, dwell_limits, min_samples
from lfd.learning.learn import FitConfig, FitError, fit
from lfd.learning.model import (
    TaskModel,
    features_tensor,
    landmarks_inverse_tensor,
    logdet_tensor,
    step_nll_tensor,
    virtual_inverse_tensor,
)
from lfd.learning.tasks import check_stride

__all__ = ["MIN_TRAIN_DEMOS", "OVERFIT_MARGIN", "OVERFIT_SD", "Comparison", "FoldReport", "SetScore", "ValidationError",
           "ValidationResult", "check_validation_set", "cross_validate", "fold_count", "fold_indices",
           "overfitting_warning", "score"]

OVERFIT_SD = 4.0  # the warning: held-out observations this many sd from their steps, RMS per feature
OVERFIT_MARGIN = OVERFIT_SD ** 2 - 1  # held-out minus training NLL per observation, in units of F (module docstring)
MIN_TRAIN_DEMOS = 2  # a fold's training part: the fit refuses to learn the environment landmark from one
DEFAULT_MAX_DWELL = FitConfig.max_dwell  # the fit's default dwell limit (lfd.learning.dtw.dwell_limits)


class ValidationError(UserInputError):
    """Validation that cannot be done as asked: folds the demonstrations cannot make (more folds
    than demonstrations, a training part too small to fit), or a set the model cannot score
    (other landmarks, robot or sampling interval, demonstrations too short to align)."""


def _finite(obj, names) -> None:
    for name in names:
        value = getattr(obj, name)
        if not (isinstance(value, (float, int)) and math.isfinite(value)):
            raise ValueError(f"{type(obj).__name__}.{name} must be a finite number, got {value!r}")
        object.__setattr__(obj, name, float(value))


@dataclass(frozen=True)
class SetScore:
    """A model's figure on a set of demonstrations (``score``), per observation, Eq. 3 units.

    nll_per_obs : the best alignments' total (observation costs and transition costs) over the
        set's observations; no priors.
    mahalanobis_per_obs : the mean squared Mahalanobis distance ``|sigma_inv_t (f - mu_t)|^2`` of
        an observation to its aligned step (F under a correct model).
    n_observations : the observations scored (after the model's subsampling).
    demo_nll_per_obs : (M,) each demonstration's ``nll_per_obs``.
    demo_mahalanobis_per_obs : (M,) each demonstration's ``mahalanobis_per_obs``.
    alignments : M int arrays ``(S_m,)``, each observation's step (0-based).
    """

    nll_per_obs: float
    mahalanobis_per_obs: float
    n_observations: int
    demo_nll_per_obs: tuple[float, ...]
    demo_mahalanobis_per_obs: tuple[float, ...]
    alignments: tuple[np.ndarray, ...] = field(compare=False, repr=False)

    def __post_init__(self):
        _finite(self, ("nll_per_obs", "mahalanobis_per_obs"))
        if self.mahalanobis_per_obs < 0:
            raise ValueError(f"SetScore.mahalanobis_per_obs must be >= 0, got {self.mahalanobis_per_obs}")
        n = self.n_observations
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"SetScore.n_observations must be a whole number >= 1, got {n!r}")
        object.__setattr__(self, "n_observations", int(n))
        per_demo = tuple(float(x) for x in self.demo_nll_per_obs)
        maha = tuple(float(x) for x in self.demo_mahalanobis_per_obs)
        if not per_demo or not all(math.isfinite(x) for x in per_demo + maha) \
                or not len(self.alignments) == len(maha) == len(per_demo):
            raise ValueError(f"SetScore: two finite figures and one alignment per demonstration, got "
                             f"{len(per_demo)} and {len(maha)} figures and {len(self.alignments)} alignments")
        if sum(len(a) for a in self.alignments) != self.n_observations:
            raise ValueError(f"SetScore: the alignments hold {sum(len(a) for a in self.alignments)} observations, "
                             f"not {self.n_observations}")
        object.__setattr__(self, "demo_nll_per_obs", per_demo)
        object.__setattr__(self, "demo_mahalanobis_per_obs", maha)


@dataclass(frozen=True)
class Comparison:
    """One model's figure on the demonstrations it was learned from (``train``) beside its figure
    on demonstrations it never saw (``heldout``); ``n_features`` its F."""

    train: SetScore
    heldout: SetScore
    n_features: int

    def __post_init__(self):
        if not (isinstance(self.train, SetScore) and isinstance(self.heldout, SetScore)):
            raise TypeError("Comparison.train and .heldout must be SetScores")
        if isinstance(self.n_features, bool) or not isinstance(self.n_features, (int, np.integer)) \
                or self.n_features < 1:
            raise ValueError(f"Comparison.n_features must be a whole number >= 1, got {self.n_features!r}")
        object.__setattr__(self, "n_features", int(self.n_features))

    @property
    def excess(self) -> float:
        """Held-out minus training NLL per observation (Eq. 3 units)."""
        return self.heldout.nll_per_obs - self.train.nll_per_obs

    @property
    def warning(self) -> str | None:
        return overfitting_warning(self.train.nll_per_obs, self.heldout.nll_per_obs,
                                   self.heldout.mahalanobis_per_obs, self.n_features)


@dataclass(frozen=True)
class FoldReport:
    """What ``cross_validate`` passes to ``progress`` after each fold (``fold`` 0-based of ``folds``)."""

    fold: int
    folds: int
    heldout_names: tuple[str, ...]
    comparison: Comparison
    fit_warnings: tuple[str, ...]
    seconds: float


def overfitting_warning(train_nll: float, heldout_nll: float, heldout_mahalanobis: float,
                        n_features: int, margin: float = OVERFIT_MARGIN) -> str | None:
    """The warning when held-out NLL per observation exceeds the training figure by more than
    ``margin * n_features`` (module docstring), else None."""
    excess = heldout_nll - train_nll
    if not excess > margin * n_features:
        return None
    return (f"held-out NLL per observation {heldout_nll:.2f} is {excess:.1f} above the training figure "
            f"{train_nll:.2f}, more than the margin of {margin:g} x F = {margin * n_features:g}: held-out "
            f"observations lie {math.sqrt(max(heldout_mahalanobis, 0.0) / n_features):.1f} standard deviations from "
            f"their steps (root mean square per feature, mean squared Mahalanobis distance {heldout_mahalanobis:.3g} "
            f"for F = {n_features}; a correct model gives about 1 sd and F): the per-step Gaussians describe the "
            f"training scenes, not the task (too many time steps for these demonstrations, variance floors too "
            f"low, or too few demonstrations)")


@dataclass(frozen=True)
class ValidationResult:
    """What ``cross_validate`` found. Figures per observation, Eq. 3 units (``score``).

    folds : K, or None when only a separate ``validation`` set was scored.
    n_demos : M, the demonstrations the folds split.
    heldout_demos : (K,) per fold the indices (into the set's demonstrations) it holds out; the
        folds partition ``range(M)``.
    fold_scores : (K,) per fold its model's ``Comparison`` of its training part and its fold.
    fold_warnings : (K,) per fold the fit's own warnings (``FitResult.warnings``).
    separate : the ``validation`` set scored by the model learned from all demonstrations,
        beside that model's score of them (None without one).
    train_nll_per_obs, heldout_nll_per_obs, train_mahalanobis_per_obs, heldout_mahalanobis_per_obs :
        (derived) the folds' observation-weighted means (every demonstration is held out once,
        so the held-out mean is the set's total over its observations); without folds, those of
        ``separate``.
    warning : (derived) ``overfitting_warning`` of the means (without folds: of ``separate``).
    separate_warning : (derived) ``separate``'s warning, None without one.
    """

    folds: int | None
    n_demos: int
    heldout_demos: tuple[tuple[int, ...], ...]
    fold_scores: tuple[Comparison, ...]
    fold_warnings: tuple[tuple[str, ...], ...]
    separate: Comparison | None = None
    train_nll_per_obs: float = field(init=False)
    heldout_nll_per_obs: float = field(init=False)
    train_mahalanobis_per_obs: float = field(init=False)
    heldout_mahalanobis_per_obs: float = field(init=False)
    warning: str | None = field(init=False)
    separate_warning: str | None = field(init=False)

    def __post_init__(self):
        K = self.folds
        if K is not None and (isinstance(K, bool) or not isinstance(K, (int, np.integer)) or K < 2):
            raise ValueError(f"ValidationResult.folds must be a whole number >= 2 or None, got {K!r}")
        k = 0 if K is None else int(K)
        if not (len(self.heldout_demos) == len(self.fold_scores) == len(self.fold_warnings) == k):
            raise ValueError(f"ValidationResult: {k} folds need as many held-out parts, comparisons and warning "
                             f"lists, got {len(self.heldout_demos)}, {len(self.fold_scores)}, "
                             f"{len(self.fold_warnings)}")
        if not all(isinstance(c, Comparison) for c in (*self.fold_scores, *([self.separate] if self.separate else []))):
            raise TypeError("ValidationResult.fold_scores and .separate must be Comparisons")
        parts = tuple(tuple(int(i) for i in p) for p in self.heldout_demos)
        if k and sorted(i for p in parts for i in p) != list(range(self.n_demos)):
            raise ValueError(f"ValidationResult.heldout_demos {parts} do not partition the {self.n_demos} "
                             f"demonstrations")
        if not k and self.separate is None:
            raise ValueError("ValidationResult: neither folds nor a separate validation set")
        object.__setattr__(self, "folds", None if K is None else int(K))
        object.__setattr__(self, "heldout_demos", parts)
        object.__setattr__(self, "fold_warnings", tuple(tuple(w) for w in self.fold_warnings))
        comparisons = self.fold_scores if k else (self.separate,)
        F = comparisons[0].n_features
        means = {}
        for side in ("train", "heldout"):
            scores = [getattr(c, side) for c in comparisons]
            n = sum(s.n_observations for s in scores)
            means[side] = (sum(s.nll_per_obs * s.n_observations for s in scores) / n,
                           sum(s.mahalanobis_per_obs * s.n_observations for s in scores) / n)
        object.__setattr__(self, "train_nll_per_obs", means["train"][0])
        object.__setattr__(self, "train_mahalanobis_per_obs", means["train"][1])
        object.__setattr__(self, "heldout_nll_per_obs", means["heldout"][0])
        object.__setattr__(self, "heldout_mahalanobis_per_obs", means["heldout"][1])
        object.__setattr__(self, "warning", overfitting_warning(means["train"][0], means["heldout"][0],
                                                                means["heldout"][1], F))
        object.__setattr__(self, "separate_warning", None if self.separate is None else self.separate.warning)

    @property
    def n_features(self) -> int:
        return (self.fold_scores[0] if self.fold_scores else self.separate).n_features  # type: ignore[union-attr]

    def summary(self) -> dict:
        """The JSON record ``lfd-train`` writes into ``summary.json`` under ``"validation"``."""
        out: dict = {"folds": self.folds, "train_nll_per_obs": self.train_nll_per_obs,
                     "heldout_nll_per_obs": self.heldout_nll_per_obs, "warning": self.warning,
                     "units": "Eq. 3 per observation (2 x NLL - F log 2 pi), no priors",
                     "n_features": self.n_features, "margin": OVERFIT_MARGIN * self.n_features,
                     "train_mahalanobis_per_obs": self.train_mahalanobis_per_obs,
                     "heldout_mahalanobis_per_obs": self.heldout_mahalanobis_per_obs}
        if self.folds is not None:
            out["fold_heldout_demos"] = [list(p) for p in self.heldout_demos]
            out["fold_train_nll_per_obs"] = [c.train.nll_per_obs for c in self.fold_scores]
            out["fold_heldout_nll_per_obs"] = [c.heldout.nll_per_obs for c in self.fold_scores]
            out["fold_fit_warnings"] = [list(w) for w in self.fold_warnings]
        if self.separate is not None:
            out["validation_set"] = {"nll_per_obs": self.separate.heldout.nll_per_obs,
                                     "mahalanobis_per_obs": self.separate.heldout.mahalanobis_per_obs,
                                     "n_demos": len(self.separate.heldout.demo_nll_per_obs),
                                     "demo_nll_per_obs": list(self.separate.heldout.demo_nll_per_obs),
                                     "train_nll_per_obs": self.separate.train.nll_per_obs,
                                     "warning": self.separate_warning}
        return out


# ----------------------------------------------------------------------------- scoring
def _scorable(model: TaskModel, demoset: DemoSet, kin) -> tuple[DemoSet, object]:
    """``demoset`` checked (``check_demoset``), at the model's sampling interval (its fit's
    ``subsample``), with what the model needs: its robot, its kept landmarks, and demonstrations
    long enough to run through its steps. Returns the set and ``kin`` in the model's dtype."""
    if not isinstance(model, TaskModel):
        raise TypeError(f"expected a TaskModel, got {type(model).__name__}")
    demoset, kin = check_demoset(demoset, kin)
    if demoset.robot != model.robot:
        raise ValidationError(f"the demonstrations were recorded on robot {demoset.robot.name!r}, the model is "
                              f"of {model.robot.name!r}")
    missing = [n for n in model.landmark_names if n not in demoset.landmark_names]
    if missing:
        raise ValidationError(f"the model needs landmark(s) {missing}, which the demonstrations do not have "
                              f"(they have {list(demoset.landmark_names)})")
    stride = check_stride(model.options.get("subsample", 1), "the model's options['subsample']")
    demoset = demoset.subsample(stride)
    if model.task is not None and not same_interval(demoset.dt, model.task.dt):
        kept = f" (1 sample in {stride} kept, as the model was learned)" if stride > 1 else ""
        raise ValidationError(f"the demonstrations are sampled every {demoset.dt:g} s{kept}, the model's steps "
                              f"every {model.task.dt:g} s")
    need = min_samples(model.time_steps, model.offsets)
    short = [d.name or str(i) for i, d in enumerate(demoset.demos) if d.n_samples < need]
    if short:
        kept = f" after keeping 1 sample in {stride}" if stride > 1 else ""
        raise ValidationError(f"demonstration(s) {short} have fewer than {need} samples{kept}, too few to run "
                              f"through the model's {model.time_steps} time steps with offsets {model.offsets}")
    return demoset, kin.to(model.dtype, model.device)


def _features(model: TaskModel, kin, demo, landmark_idx: list[int]) -> torch.Tensor:
    """Eq. 2 for one demonstration under the model: ``f (S, F)``; its landmarks still ``(Z_all, 4,
    4)`` or tracked ``(S, Z_all, 4, 4)``, of which the model's kept ones (``landmark_idx``)."""
    q = torch.as_tensor(demo.q, dtype=model.dtype, device=model.device)  # (S, d)
    lm = torch.as_tensor(np.asarray(demo.landmarks)[..., landmark_idx, :, :], dtype=model.dtype,
                         device=model.device)  # (Z, 4, 4) or (S, Z, 4, 4)
    K = virtual_inverse_tensor(model.env, landmarks_inverse_tensor(lm.reshape(-1, *lm.shape[-3:])))  # (1 or S, 4, 4)
    return features_tensor(q, kin.fk(q), model.tool, K[0] if lm.dim() == 3 else K, model.feature_set)


def score(model: TaskModel, demoset: DemoSet, *, max_dwell: float | None = DEFAULT_MAX_DWELL,
          kin=None) -> SetScore:
    """The model's negative log-likelihood of ``demoset`` per observation (module docstring).

    Parameters
    ----------
    model : a learned ``TaskModel``.
    demoset : demonstrations as recorded (the model's ``options['subsample']`` is applied, as
        the fit applied it), with the model's robot and at least its kept landmarks.
    max_dwell : the fit's ``FitConfig.max_dwell`` (the dwell limit of the alignment, which the
        model does not record; None: unlimited).
    kin : a ``KinematicModel`` of the robot (None: built).

    Raises
    ------
    ValidationError (a ``lfd.errors.UserInputError``)
        another robot, a missing landmark, another sampling interval, demonstrations too short.
    lfd.learning.demoset.DemoFormatError
        demonstrations ``load_demos`` would refuse.
    """
    demoset, kin = _scorable(model, demoset, kin)
    idx = [demoset.landmark_index(n) for n in model.landmark_names]
    lengths = [d.n_samples for d in demoset.demos]
    with torch.no_grad():
        costs = [step_nll_tensor(_features(model, kin, d, idx), model.mu, model.sigma_inv, model.logdet_scale)
                 for d in demoset.demos]  # M x (S_m, T)
        cost = pad_sequence(costs, batch_first=True)  # (M, S_max, T), zeros past each end
        align, values = dtw_align(cost, lengths, model.trans_cost, model.offsets,
                                  dwell_limits(lengths, model.time_steps, max_dwell))
        logdet = model.logdet_scale * logdet_tensor(model.sigma_inv)  # (T,)
        at = [torch.as_tensor(a, device=model.device) for a in align]
        maha = [float((c[torch.arange(len(a)), a] - logdet[a]).sum()) for c, a in zip(costs, at)]  # (M,)
    n = sum(lengths)
    vals = values.cpu().numpy()
    return SetScore(nll_per_obs=float(vals.sum()) / n, mahalanobis_per_obs=sum(maha) / n, n_observations=n,
                    demo_nll_per_obs=tuple(float(v) / s for v, s in zip(vals, lengths)),
                    demo_mahalanobis_per_obs=tuple(x / s for x, s in zip(maha, lengths)), alignments=tuple(align))


# ----------------------------------------------------------------------------- folds
def fold_count(folds, n_demos: int) -> int:
    """K for ``folds`` (a whole number, or ``'loo'``: one fold per demonstration) over ``n_demos``
    demonstrations; ``ValidationError`` when the folds cannot be made or a training part (the
    other folds) would hold fewer than ``MIN_TRAIN_DEMOS`` demonstrations."""
    if isinstance(folds, str) and folds.lower() == "loo":
        K = n_demos
    elif isinstance(folds, bool) or not isinstance(folds, (int, np.integer)):
        raise ValidationError(f"folds must be a whole number >= 2 or 'loo' (leave one out), got {folds!r}")
    else:
        K = int(folds)
    if K < 2:
        raise ValidationError(f"{K} fold(s): cross-validation needs at least 2 folds (or 'loo', leave one out)")
    if K > n_demos:
        raise ValidationError(f"{K} folds of {n_demos} demonstrations: each fold holds out whole demonstrations, "
                              f"so there can be at most {n_demos} folds ('loo', leave one out)")
    smallest = n_demos - math.ceil(n_demos / K)
    if smallest < MIN_TRAIN_DEMOS:
        raise ValidationError(f"{K} folds of {n_demos} demonstrations leave {smallest} demonstration(s) to learn "
                              f"from in a fold, fewer than the {MIN_TRAIN_DEMOS} a fit needs (more demonstrations, "
                              f"or more folds)")
    return K


def fold_indices(n_demos: int, folds, seed: int) -> tuple[tuple[int, ...], ...]:
    """The demonstrations each fold holds out: ``fold_count(folds, n_demos)`` parts of a random
    permutation of ``range(n_demos)`` drawn with ``seed``, sizes within one of each other,
    each sorted."""
    K = fold_count(folds, n_demos)
    perm = np.random.default_rng(seed).permutation(n_demos)
    return tuple(tuple(sorted(int(i) for i in part)) for part in np.array_split(perm, K))


def _subset(demoset: DemoSet, idx: Sequence[int]) -> DemoSet:
    return replace(demoset, demos=tuple(demoset.demos[i] for i in idx))


def check_validation_set(demoset: DemoSet, validation: DemoSet, config: FitConfig | None = None) -> None:
    """``ValidationError`` unless ``validation`` can be scored beside ``demoset``: the same robot,
    landmarks (names and order), sampling interval and task (when both name one), none of its
    demonstrations also among ``demoset``'s (``lfd.learning.demo_checks.unusable_demos``: the same
    joint trajectory), and, with ``config``, each long enough for its time steps (as the fit
    checks its own, after its ``subsample``)."""
    if validation.robot != demoset.robot:
        raise ValidationError(f"the validation demonstrations were recorded on robot {validation.robot.name!r}, "
                              f"the training demonstrations on {demoset.robot.name!r}")
    if tuple(validation.landmark_names) != tuple(demoset.landmark_names):
        raise ValidationError(f"the validation demonstrations have landmarks {list(validation.landmark_names)}, "
                              f"the training demonstrations {list(demoset.landmark_names)}")
    if not same_interval(validation.dt, demoset.dt):
        raise ValidationError(f"the validation demonstrations are sampled every {validation.dt:g} s, the training "
                              f"demonstrations every {demoset.dt:g} s")
    if validation.task is not None and demoset.task is not None and validation.task.name != demoset.task.name:
        raise ValidationError(f"the validation demonstrations are of task {validation.task.name!r}, the training "
                              f"demonstrations of {demoset.task.name!r}")
    if config is not None:
        need = min_samples(config.time_steps, config.offsets)
        short = [d.name or str(i) for i, d in enumerate(validation.subsample(config.subsample).demos)
                 if d.n_samples < need]
        if short:
            kept = f" after keeping 1 sample in {config.subsample}" if config.subsample > 1 else ""
            raise ValidationError(f"validation demonstration(s) {short} have fewer than {need} samples{kept}, too "
                                  f"few for {config.time_steps} time steps with offsets {config.offsets}")
    demos = [*demoset.demos, *validation.demos]
    names = [f"training {d.name or i}" for i, d in enumerate(demoset.demos)]
    names += [f"validation {d.name or i}" for i, d in enumerate(validation.demos)]
    why = unusable_demos([np.asarray(d.q) for d in demos], names)
    if why:
        raise ValidationError(f"the validation set: {why}")


def _fit_quietly(demoset: DemoSet, kin, cfg: FitConfig, workers: int | None):
    """``fit``, its warnings kept in its result instead of shown (a fold's notes are the
    ``ValidationResult``'s ``fold_warnings``)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=RuntimeWarning, module=r"lfd\.learning\.learn")
        return fit(demoset, kin, cfg, workers=workers, uncertainty=False)  # (no fold reports its standard errors)


def cross_validate(demoset: DemoSet, kin=None, config: FitConfig | None = None, folds: int | str | None = 5,
                   validation: DemoSet | None = None, model: TaskModel | None = None,
                   progress: Callable[[FoldReport], None] | None = None,
                   workers: int | None = None) -> ValidationResult:
    """K-fold validation over whole demonstrations, and the score of a separate set.

    Parameters
    ----------
    demoset, kin, config : as ``lfd.learning.learn.fit`` takes them; every fold fits with ``config``.
    folds : K >= 2, ``'loo'`` (one fold per demonstration), or None (no folds: ``validation``
        alone). The folds are drawn from ``config.seed`` (``fold_indices``).
    validation : a separate ``DemoSet`` (same robot, landmarks and sampling interval,
        ``check_validation_set``), scored by ``model``.
    model : the model learned from all of ``demoset`` with ``config`` (e.g. ``FitResult.model``
        of the run being validated); fitted here when ``validation`` is given without it.
    progress : called with a ``FoldReport`` after each fold.
    workers : restarts at once in each fit (``fit``).

    Raises
    ------
    ValidationError (a ``lfd.errors.UserInputError``)
        folds that cannot be made (``fold_count``), a validation set that cannot be scored.
    FitError
        a fold's fit that failed, its message prefixed with the fold.
    """
    cfg = config or FitConfig()
    demoset, kin = check_demoset(demoset, kin)
    if folds is None and validation is None:
        raise ValidationError("nothing to validate: give folds, a validation set, or both")
    parts = fold_indices(len(demoset.demos), folds, cfg.seed) if folds is not None else ()
    if validation is not None:
        validation, _ = check_demoset(validation, kin)
        check_validation_set(demoset, validation, cfg)
    scored, notes = [], []
    for k, held in enumerate(parts):
        t0 = time.perf_counter()
        train = _subset(demoset, [i for i in range(len(demoset.demos)) if i not in held])
        heldout = _subset(demoset, held)
        names = tuple(d.name or str(i) for i, d in zip(held, heldout.demos))
        try:
            result = _fit_quietly(train, kin, cfg, workers)
        except FitError as e:
            raise FitError(f"validation fold {k + 1} of {len(parts)} (held out {list(names)}): {e}") from e
        m = result.model
        comparison = Comparison(score(m, train, max_dwell=cfg.max_dwell, kin=kin),
                                score(m, heldout, max_dwell=cfg.max_dwell, kin=kin), m.n_features)
        scored.append(comparison)
        notes.append(tuple(result.warnings))
        if progress is not None:
            progress(FoldReport(k, len(parts), names, comparison, tuple(result.warnings), time.perf_counter() - t0))
    separate = None
    if validation is not None:
        if model is None:
            model = _fit_quietly(demoset, kin, cfg, workers).model
        separate = Comparison(score(model, demoset, max_dwell=cfg.max_dwell, kin=kin),
                              score(model, validation, max_dwell=cfg.max_dwell, kin=kin), model.n_features)
    return ValidationResult(folds=len(parts) or None, n_demos=len(demoset.demos), heldout_demos=parts,
                            fold_scores=tuple(scored), fold_warnings=tuple(notes), separate=separate)
