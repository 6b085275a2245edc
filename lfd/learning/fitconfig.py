"""The learner's settings (``FitConfig``, with their choices) and what it returns (``FitResult``).

``lfd.learning.learn.fit`` takes the one and returns the other; both are re-exported there.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from lfd.errors import UserInputError
from lfd.learning.model import COVARIANCES, FEATURE_SETS, TaskModel
from lfd.learning.tasks import check_stride, check_whole, is_real
from lfd.learning.uncertainty import Uncertainty

__all__ = ["DTYPES", "ENV_MODES", "ENV_WEIGHTS", "INITS", "M_STEPS", "TOOL_MODES", "FitConfig", "FitError",
           "FitResult", "SolverSettings"]

TOOL_MODES = ("learn", "gripper", "tip")
ENV_MODES = ("learn", "bowl")
ENV_WEIGHTS = ("simplex", "affine")
M_STEPS = ("profile", "joint")
INITS = ("reference", "random", "linear")
DTYPES = {"float64": torch.float64, "float32": torch.float32}
# The widest variance floors (standard deviations) that still say something: wider than a feature's
# whole range, a floor only flattens that feature's term, and past ~1e154 its square overflows and
# every restart fails in a Cholesky factorization (measured: ``--floor-joint 1e308``). Joints: a full
# turn (rad), wider than any revolute joint's travel; the tool point: 10 m, wider than any arm's
# workspace; the attitude: 2, the widest spread of a unit vector's component.
FLOOR_LIMITS = {"floor_joint": 2 * math.pi, "floor_task": 10.0, "floor_attitude": 2.0}


def _check_numbers(obj, names) -> None:
    """``ValueError`` naming the first field of ``obj`` among ``names`` that is not a real number
    (None passes: the fields that take it say what it means; a string gave Python's TypeError
    from a comparison, naming no field); each number is stored as a Python ``float``, so that a
    NumPy scalar given for it is written to the model's and the checkpoint's JSON like any other."""
    for name in names:
        value = getattr(obj, name)
        if value is not None and not is_real(value):
            raise ValueError(f"{type(obj).__name__}.{name} must be a number, got {value!r}")
        if value is not None:
            object.__setattr__(obj, name, float(value))


def _store_whole(obj, names, minimum: int) -> None:
    """Each of ``obj``'s fields ``names`` checked (``check_whole``) and stored as a Python ``int``."""
    for name in names:
        object.__setattr__(obj, name, check_whole(getattr(obj, name), f"{type(obj).__name__}.{name}", minimum))


class FitError(UserInputError):
    """The fit cannot give a model for these demonstrations and settings: too few samples for the
    time steps, one demonstration for a learned environment landmark, a fixed landmark without
    its task.json, every restart failed, a non-finite model. The message says which, and what to
    change."""


@dataclass(frozen=True)
class SolverSettings:
    """How ``fit`` optimizes, not what it fits (``FitConfig.solver``); the defaults are the ones
    every result in docs/ was made with.

    max_em_iters, em_tol : EM stops after this many iterations, or when the per-observation loss
        changes less than ``em_tol`` (or the alignments repeat).
    lbfgs_max_iter, lbfgs_history, lbfgs_tol_grad : each M-step's LBFGS (``torch.optim.LBFGS``,
        strong Wolfe line search).
    m_step : 'profile' (default: LBFGS over zeta with eta in closed form) or 'joint' (then LBFGS
        over zeta and eta together, ``joint_max_iter`` iterations; forced by an ``eta_prior``).
    tool_init_std : spread (m) of the restarts' random tool-point starts (the first starts at 0).
    tool_search, tool_grid : before each restart's first M-step the tool point's start is the
        best of the current guess and a ``tool_grid^3`` grid spanning ``+-tool_search`` m per
        axis, by the profiled loss (0 disables); LBFGS is local and the loss is not convex in it.
    num_threads : torch CPU threads during the fit (restored afterwards); the tensors are
        small, so one thread is fastest and immune to oversubscription; None leaves it alone.
    """

    max_em_iters: int = 25
    em_tol: float = 1e-5
    lbfgs_max_iter: int = 50
    lbfgs_history: int = 20
    lbfgs_tol_grad: float = 1e-7
    m_step: str = "profile"
    joint_max_iter: int = 200
    tool_init_std: float = 0.15
    tool_search: float = 0.2
    tool_grid: int = 5
    num_threads: int | None = 1

    def __post_init__(self):
        if self.m_step not in M_STEPS:
            raise ValueError(f"SolverSettings.m_step must be one of {', '.join(M_STEPS)}; got {self.m_step!r}")
        _store_whole(self, ("max_em_iters", "lbfgs_max_iter", "lbfgs_history", "joint_max_iter", "tool_grid"), 1)
        _check_numbers(self, ("em_tol", "lbfgs_tol_grad", "tool_init_std", "tool_search"))
        if not (self.em_tol >= 0 and self.lbfgs_tol_grad >= 0 and self.tool_init_std >= 0):
            raise ValueError("SolverSettings.em_tol, lbfgs_tol_grad and tool_init_std must be >= 0, got "
                             f"{self.em_tol}, {self.lbfgs_tol_grad}, {self.tool_init_std}")
        if not self.tool_search >= 0:  # NaN too
            raise ValueError(f"SolverSettings.tool_search must be >= 0, got {self.tool_search}")
        if self.num_threads is not None:
            _store_whole(self, ("num_threads",), 1)


@dataclass(frozen=True)
class FitConfig:
    """Settings of ``fit``. Lengths in metres, angles in radians, losses in Eq. 3 units.

    tool : 'learn' | 'gripper' (fixed at the end-effector origin) | 'tip' (task.manual_tool_point).
    env : 'learn' | 'bowl' (one-hot on task.reference_landmark).
    env_weights : the environment weights a learned landmark may take. 'simplex' (default; Sec. IV-A:
        sum 1 with the L1 norm constrained, i.e. each in [0, 1]): the virtual landmark lies among the
        sensed ones. 'affine': sum 1, any sign, so it may also lie beyond them (the weights'
        parametrisation: ``lfd.learning.em.EMFitter.weights``; the measured reason to keep it:
        docs/DESIGN.md, *Environment weights and what the demonstrations leave uncertain*).
    offsets : the permitted time-step transitions ``t -> t + k`` (the paper fixes a set and
        estimates their probabilities; it does not name the set). Default ``(0, 1)``: every
        demonstration visits every step, so no step is left to the one or two demonstrations
        that did not skip it. With ``(0, 1, 2)`` (the model's default set, ``lfd.learning.dtw.OFFSETS``)
        hard EM skipped steps to give them to single demonstrations; measured on the pour's
        draw 2 (docs/EXPERIMENTS.md): steps resting on one demonstration whose joint covariance
        made every other arm posture cost 10^5, and 84% -> 90% of the 50 pour scenes with (0, 1).
        Each demonstration then needs at least ``time_steps`` samples (``lfd.learning.dtw.min_samples``).
    covariance : 'block' (default: joints, tool point and attitude independent of each other
        while zeta is learned; the model's final Gaussians keep the tool point and the attitude
        in one block, ``EMFitter.final_eta``) | 'full' (the paper). While zeta is learned the
        attitude needs its own block as the joints do: the tool point's offset ``A R tool`` is
        linear in the gripper's axes, so in one block with them the tool point's x and y would be
        absorbed by the regression (measured on the powder set: 4.7 cm from the hidden task point
        with one task block, against 1.3 cm without the attitude). Once zeta is learned, the
        model says how the tool point's place varies with the attitude: a pour draw whose learned
        point sits at the spout, whose place beside the bowl turns with the direction the bowl
        is faced from, poured 44% of 50 scenes with the three blocks and 90% of the same 50 with
        one task block (docs/EXPERIMENTS.md, *A tool point whose place turns with the attitude*).
        With 'full', zeta enters the likelihood only through the task features' residual
        *given* the joints; as the tool point's world position is a smooth function of q,
        changing the tool point is largely absorbed by that regression and the tool point is
        nearly unidentifiable (measured: 17-45 cm error vs 0.5-2.2 cm for 'block' on synthetic
        data with known truth, see benchmarks/learning.py --compare).
    subsample : learn from every ``subsample``-th sample of each demonstration
        (``DemoSet.subsample``; the model's ``task.dt`` becomes ``subsample`` times the
        demonstrations'). The paper's remedy for its 50 Hz pour demonstrations (Sec. VI-B).
    logdet_scale : ``s`` in ``s log|Sigma|`` (1 = maximum likelihood).
    features : 'paper' (Eq. 2: joint angles and the tool point in the virtual landmark frame) or
        'attitude' (those and the gripper's x and y axes in that frame; lfd.learning.model).
    floor_joint, floor_task, floor_attitude : the variance-floor prior's standard deviations
        (lfd.learning.priors) of the joint angles (rad), the tool point (m) and the axes (unit
        vectors' components); at most ``FLOOR_LIMITS``' (a full turn, 10 m, 2).
    floor_weight : its pseudo-observations ``nu``; None = mean observations per time step.
    volume_prior : add ``-2 s k log|det A|`` per observation (``k`` task 3-vectors; lfd.learning.priors); zero for aligned frames.
    tool_radius : metres from the gripper's origin the learned tool point may lie (the tool's
        size): beyond it a steep penalty holds it, so that a component the demonstrations cannot
        determine (the gripper never turned about that axis, ``lfd.learning.identify``) stays on
        the tool instead of drifting off to metres; inside it the objective is the paper's.
    tool_size : metres from the gripper's origin within which a tool point is taken to lie on the
        tool (default 0.25: a hand tool held in the gripper); beyond it ``fit`` warns, saying whether
        the demonstrations place the point there or cannot place it (``lfd.learning.uncertainty``).
        It changes no learned value; at most ``tool_radius``.
    trans_floor : smallest probability of a permitted transition.
    restarts : EM runs from different starts (``init``); the best by loss is kept. Each ends in a
        local optimum of hard EM, and their losses spread widely (powder demonstrations aimed
        with another task point: -39.5 to -44.7 per observation over 12): the best of the first
        4 left two demonstrations' dumps on other steps than the rest's, the best of 12 aligned
        them all (docs/EXPERIMENTS.md).
    init : how each restart's first alignments are drawn. 'reference' (default): every
        demonstration is warped by DTW of its joint angles onto one reference demonstration
        (the median-length one, uniformly split into steps, for the first restart; a random
        one with a random warp for the others), so a step starts as the same phase everywhere.
        'linear': every restart from the uniform time warp (each demonstration split into T
        equal parts; restarts differ in the tool point's and weights' starts); with ``band=0``
        the alignment stays there, so every step rests on every demonstration alike.
        'random': an independent random warp per demonstration, as in the paper. Measured on
        the 50 Hz pour set: with 'random' the EM settled with each demonstration's whole
        pouring phase on one step, a different step per demonstration (see README).
    band : the E-step keeps every sample within ``band`` steps of the restart's starting
        alignment (a Sakoe-Chiba band; None = unconstrained, as in the paper). Hard EM with an
        unconstrained DTW drifts to alignments of higher likelihood that squeeze one
        demonstration's whole pouring phase onto a single broad step; with band 1 every step
        of the 50 Hz pour set keeps one phase (see README, "Learning").
    max_dwell : the most consecutive samples a demonstration may spend at one step, as a multiple
        of its mean per step (``ceil(max_dwell * S_m / T)``, ``lfd.learning.dtw.dwell_limits``);
        default 2; None = unlimited, as in the paper. Hard EM reaches a higher likelihood by giving each
        demonstration's still phase (a pitcher held while it pours: 40-97 samples) a step of
        its own, so such a step's Gaussian rests on one demonstration; the limit makes every
        demonstration spread a long phase over several steps, which the others share.
    solver : how the fit optimizes (``SolverSettings``): iteration limits and tolerances, the
        M-step's form, the tool point's starting search, CPU threads. Not what it fits.
    zeta_prior, eta_prior : extra terms of the objective, ``zeta_prior(tool, w)`` and
        ``eta_prior(mu, sigma_inv)`` -> a scalar tensor (None: none). The restarts run in
        threads (``fit(workers=)``), so they are called from several threads at once and must
        not keep state between calls.
    """

    time_steps: int = 24
    subsample: int = 1
    offsets: tuple[int, ...] = (0, 1)
    restarts: int = 12
    tool: str = "learn"
    env: str = "learn"
    env_weights: str = "simplex"
    covariance: str = "block"
    prune_threshold: float = 0.05
    seed: int = 0
    device: str = "cpu"
    dtype: str = "float64"
    logdet_scale: float = 1.0
    floor_joint: float = 1e-3
    floor_task: float = 1e-3
    floor_attitude: float = 1e-2
    features: str = "paper"
    floor_weight: float | None = None
    volume_prior: bool = True
    trans_floor: float = 0.01
    init: str = "reference"
    band: int | None = 1
    max_dwell: float | None = 2.0
    tool_radius: float = 0.5
    tool_size: float = 0.25
    solver: SolverSettings = field(default_factory=SolverSettings)
    zeta_prior: Callable | None = field(default=None, compare=False)
    eta_prior: Callable | None = field(default=None, compare=False)

    def __post_init__(self):
        for name, allowed in (("tool", TOOL_MODES), ("env", ENV_MODES), ("env_weights", ENV_WEIGHTS),
                              ("covariance", COVARIANCES),
                              ("init", INITS), ("dtype", tuple(DTYPES)), ("features", FEATURE_SETS)):
            value = getattr(self, name)
            if value not in allowed:
                raise ValueError(f"FitConfig.{name} must be one of {', '.join(allowed)}; got {value!r}")
        try:  # any torch device string: cpu, cuda, cuda:1, mps, ...
            torch.device(self.device)
        except (RuntimeError, ValueError, TypeError) as e:
            raise ValueError(f"FitConfig.device must be a torch device string (cpu, cuda, cuda:1, mps, ...); "
                             f"got {self.device!r}") from e
        object.__setattr__(self, "time_steps", check_whole(self.time_steps, "FitConfig.time_steps", 2))
        object.__setattr__(self, "restarts", check_whole(self.restarts, "FitConfig.restarts", 1))
        _check_numbers(self, ("prune_threshold", "logdet_scale", "floor_joint", "floor_task", "floor_attitude",
                              "floor_weight", "trans_floor", "max_dwell", "tool_radius", "tool_size"))
        if not isinstance(self.solver, SolverSettings):
            raise TypeError(f"FitConfig.solver must be a SolverSettings, got {type(self.solver).__name__}")
        if self.band is not None:  # wider than the model would constrain nothing: that is None
            object.__setattr__(self, "band", check_whole(self.band, "FitConfig.band", 0))
            if self.band > int(self.time_steps):
                raise ValueError(f"FitConfig.band must be at most time_steps ({self.time_steps}) or None "
                                 f"(unconstrained), got {self.band}")
        if self.max_dwell is not None and not (math.isfinite(self.max_dwell) and self.max_dwell >= 1):
            raise ValueError(f"FitConfig.max_dwell must be at least 1 (a demonstration's mean samples per "
                             f"step) or None (unlimited), got {self.max_dwell}")
        _store_whole(self, ("seed",), 0)
        if self.seed >= 2**63:  # numpy and torch both take it
            raise ValueError(f"FitConfig.seed must be a whole number in [0, 2**63), got {self.seed!r}")
        if not isinstance(self.volume_prior, (bool, np.bool_)):  # a string such as 'false' is truthy
            raise TypeError(f"FitConfig.volume_prior must be True or False, got {self.volume_prior!r}")
        object.__setattr__(self, "volume_prior", bool(self.volume_prior))
        object.__setattr__(self, "subsample", check_stride(self.subsample, "FitConfig.subsample"))
        if isinstance(self.offsets, (str, bytes)) or not len(self.offsets):
            raise ValueError(f"FitConfig.offsets must be a sequence of whole numbers, got {self.offsets!r}")
        object.__setattr__(self, "offsets", tuple(check_whole(k, "each of FitConfig.offsets", 0)
                                                  for k in self.offsets))
        if len(set(self.offsets)) != len(self.offsets) or not {0, 1} <= set(self.offsets):
            raise ValueError(f"FitConfig.offsets must be distinct, non-negative and include 0 and 1 (a "
                             f"sample may stay in its step or move to the next); got {self.offsets}")
        largest = max(2, int(self.time_steps) // 2)
        if max(self.offsets) > largest:  # was accepted: 30 of 48 let a sample skip most of the task
            raise ValueError(f"FitConfig.offsets: {max(self.offsets)} is larger than the largest permitted, "
                             f"max(2, time_steps // 2) = {largest} (an offset k moves a sample k steps on; "
                             f"the usual sets are small: 0, 1, 2)")
        if not all(math.isfinite(x) and x > 0 for x in (self.floor_joint, self.floor_task, self.floor_attitude)):
            raise ValueError(f"FitConfig.floor_joint, floor_task and floor_attitude must be positive standard "
                             f"deviations, got {self.floor_joint}, {self.floor_task}, {self.floor_attitude}")
        for name, widest in FLOOR_LIMITS.items():
            if getattr(self, name) > widest:
                raise ValueError(f"FitConfig.{name} must be at most {widest:.4g}, wider than the feature's whole "
                                 f"range (a floor that wide only flattens its term), got {getattr(self, name):g}")
        if self.floor_weight is not None and not (math.isfinite(self.floor_weight) and self.floor_weight > 0):
            raise ValueError(f"FitConfig.floor_weight must be a positive number of pseudo-observations or None "
                             f"(the mean observations per step), got {self.floor_weight}")
        if not (math.isfinite(self.tool_radius) and self.tool_radius > 0):
            raise ValueError(f"FitConfig.tool_radius must be a positive distance in metres, got {self.tool_radius}")
        if not (math.isfinite(self.tool_size) and 0 < self.tool_size <= self.tool_radius):
            raise ValueError(f"FitConfig.tool_size must be a positive distance in metres, at most tool_radius "
                             f"({self.tool_radius:g}), got {self.tool_size}")
        if not (math.isfinite(self.logdet_scale) and self.logdet_scale > 0):
            raise ValueError(f"FitConfig.logdet_scale must be finite and positive, got {self.logdet_scale}")
        if not 0 <= self.prune_threshold < 1:
            raise ValueError(f"FitConfig.prune_threshold must be in [0, 1), got {self.prune_threshold}")
        if not 0 < self.trans_floor < 1.0 / len(self.offsets):
            raise ValueError(f"FitConfig.trans_floor must be in (0, 1/K), got {self.trans_floor}")


@dataclass(frozen=True)
class FitResult:
    """What ``fit`` found. Losses are per observation, Eq. 3 units (negative log posterior)."""

    model: TaskModel
    loss_history: tuple[tuple[float, ...], ...]  # per restart, then each refit after pruning
    em_iterations: tuple[int, ...]
    final_loss: float  # the model's parameters at their best alignment (the EM's last E-step's)
    restart_losses: tuple[float, ...]  # nan for a dropped restart
    best_restart: int
    kept_landmarks: tuple[str, ...]
    env_before_pruning: dict
    alignments: tuple[np.ndarray, ...]
    virtual_det: tuple[float, ...]  # |det A| of K_virt^-1's linear part, per demonstration (its least when tracked)
    effective_demos: tuple[float, ...]  # per step, in the final alignment (lfd.learning.dtw.effective_demos);
    # a warning when the median is under M / 3 (with M >= 4 demonstrations)
    warnings: tuple[str, ...]
    timings: dict  # s: fk_s, restarts_s, refit_s, uncertainty_s and session_s of this call; total_s with the
    # resumed sessions'
    resumed_restarts: int = 0  # restarts taken from a checkpoint instead of run
    uncertainty: Uncertainty | None = None  # the tool point's and weights' standard errors, the landmarks that
    # explain the data about equally (lfd.learning.uncertainty)

    @property
    def tool_se(self) -> np.ndarray | None:
        """``(3,)`` m: the learned tool point's standard error per axis of the gripper frame (``inf``
        along an axis the demonstrations do not determine); None when it was not learned."""
        return None if self.uncertainty is None else self.uncertainty.tool_se


