"""The learned task model: virtual landmarks (zeta), per-step Gaussians (eta), transitions.

Notation follows the paper (Sec. III-IV). Conventions written once here:

* ``F = d + 3`` features per configuration (Eq. 2, feature set ``'paper'``): the ``d`` joint
  angles, then the tool point ``zeta_tool`` (end-effector frame, metres) expressed in the
  environmental virtual landmark frame: ``x = K_virt^-1 @ T_world_ee @ [tool; 1]``.
* Feature set ``'attitude'`` (a deviation from the paper, docs/DESIGN.md): ``F = d + 9``, Eq. 2's
  features followed by the end effector's x and y axes in the same frame,
  ``A R_world_ee[:, 0]`` and ``A R_world_ee[:, 1]`` (``A`` the linear part of ``K_virt^-1``):
  the gripper's attitude relative to the environment, which the joint angles give only through
  the arm's posture. The task features of either set are ``K_virt^-1`` applied to ``k`` world
  vectors ``P (N, k, 3)`` (``task_vectors_tensor``): the tool point (a point) then the axes
  (directions, no translation).
* ``K_virt^-1 = sum_i env_i * inv(T_world_landmark_i)`` (a 4x4 affine map, rigid only when
  the landmark rotations agree); ``sum(env) == 1``.
* **Eq. 3 units.** Every cost in lfd's learning and planning is in the units of Eq. 3:
  ``L(q | zeta, eta_t, a) = s * log|Sigma_t| + |sigma_inv_t (f - mu_t)|^2``, i.e. twice the
  Gaussian negative log-likelihood minus the constant ``F log(2 pi)`` (``s`` = ``logdet_scale``,
  1 by default, which makes it exactly that). Transition costs in the same units are
  ``-2 * log p(t'|t)`` (``TaskModel.trans_cost``); ``log_trans`` itself is the natural log.
* ``sigma_inv_t`` is the inverse of the lower Cholesky factor of ``Sigma_t``
  (``Sigma = sigma sigma^T``), lower-triangular with a positive diagonal, so
  ``log|Sigma| = -2 sum log diag(sigma_inv)``.
"""

from __future__ import annotations

import json
import math
import numbers
import pickle
from pathlib import Path

import numpy as np
import torch

from lfd.errors import UserInputError
from lfd.learning.dtw import OFFSETS
from lfd.learning.tasks import FEATURE_SETS, TASK_VECTORS, TaskSpec, check_names
from lfd.robot.device import usable_device
from lfd.robot.robots import RobotSpec

__all__ = [
    "COVARIANCES",
    "FEATURE_SETS",
    "FORMAT",
    "MAX_FEATURE",
    "MODEL_DTYPES",
    "OFFSETS",
    "ModelFormatError",
    "TaskModel",
    "aligned_nll_tensor",
    "features_tensor",
    "landmarks_inverse_tensor",
    "logdet_tensor",
    "reaches_last_step",
    "step_nll_tensor",
    "task_features_tensor",
    "task_vectors_tensor",
    "virtual_inverse_tensor",
]

COVARIANCES = ("full", "block")
FORMAT = "lfd-task-model/1"
MAX_FEATURE = 1e3  # no feature's mean (rad, m) is larger in a model that was learned
# what a model computes in: torch's linear algebra (Cholesky, inverses) refuses half precision,
# and bfloat16's 8 bits of mantissa fail the model's own checks
MODEL_DTYPES = (torch.float32, torch.float64)


class ModelFormatError(UserInputError):
    """A model folder that is not an lfd task model (or a damaged one)."""


def _check_dtype(dtype) -> None:
    """``TypeError`` unless ``dtype`` is one of ``MODEL_DTYPES``."""
    if not (isinstance(dtype, torch.dtype) and dtype in MODEL_DTYPES):
        raise TypeError(f"a task model's dtype must be torch.float64 or torch.float32, got {dtype!r}")


# ----------------------------------------------------------------------------- kernels
def landmarks_inverse_tensor(T_world_landmark: torch.Tensor) -> torch.Tensor:
    """``(..., Z, 4, 4) -> T_landmark_world (..., Z, 4, 4)`` for rigid transforms."""
    R = T_world_landmark[..., :3, :3]
    Rt = R.transpose(-1, -2)
    t = -(Rt @ T_world_landmark[..., :3, 3:4])
    top = torch.cat([Rt, t], dim=-1)  # (..., 3, 4)
    bottom = torch.zeros_like(T_world_landmark[..., 3:4, :])
    bottom[..., 0, 3] = 1
    return torch.cat([top, bottom], dim=-2)


def virtual_inverse_tensor(env: torch.Tensor, T_landmark_world: torch.Tensor) -> torch.Tensor:
    """``K_virt^-1 = sum_i env_i T_landmark_i_world``: env ``(Z,)``, ``(M, Z, 4, 4) -> (M, 4, 4)``."""
    return torch.einsum("z,mzij->mij", env, T_landmark_world)


def task_vectors_tensor(T_world_ee: torch.Tensor, tool: torch.Tensor, feature_set: str = "paper") -> torch.Tensor:
    """The world vectors the task features are made of: ``T_world_ee (N, 4, 4)``, ``tool (3,)``
    -> ``P (N, k, 3)``: the tool point, then (``'attitude'``) the end effector's x and y axes."""
    R = T_world_ee[:, :3, :3]
    p = (R @ tool + T_world_ee[:, :3, 3])[:, None]  # (N, 1, 3)
    if feature_set == "paper":
        return p
    if feature_set != "attitude":
        raise ValueError(f"feature set must be one of {FEATURE_SETS}, got {feature_set!r}")
    return torch.cat([p, R[:, :, :2].transpose(1, 2)], dim=1)  # (N, 3, 3)


def task_features_tensor(P: torch.Tensor, K_virt_inv: torch.Tensor) -> torch.Tensor:
    """``K_virt^-1`` applied to ``P (N, k, 3)`` (row 0 a point, the others directions); ``K_virt_inv``
    ``(4, 4)`` or ``(N, 4, 4)`` -> ``x (N, 3k)``."""
    if K_virt_inv.dim() == 2:
        x = P @ K_virt_inv[:3, :3].T  # (N, k, 3)
        b = K_virt_inv[:3, 3].expand(len(P), 3)
    else:
        x = torch.einsum("nij,nkj->nki", K_virt_inv[:, :3, :3], P)
        b = K_virt_inv[:, :3, 3]
    return torch.cat([x[:, 0] + b, x[:, 1:].reshape(len(P), -1)], dim=1)


def features_tensor(q: torch.Tensor, T_world_ee: torch.Tensor, tool: torch.Tensor,
                    K_virt_inv: torch.Tensor, feature_set: str = "paper") -> torch.Tensor:
    """Eq. 2 (and the attitude, for ``'attitude'``). ``q (N, d)``, ``T_world_ee (N, 4, 4)``,
    ``tool (3,)``, ``K_virt_inv (N, 4, 4)`` or ``(4, 4)`` -> ``f (N, d + 3k)``."""
    P = task_vectors_tensor(T_world_ee, tool, feature_set)
    return torch.cat([q, task_features_tensor(P, K_virt_inv)], dim=-1)


def logdet_tensor(sigma_inv: torch.Tensor) -> torch.Tensor:
    """``log|Sigma|`` from ``sigma_inv (..., F, F)`` -> ``(...)``."""
    return -2.0 * torch.log(torch.diagonal(sigma_inv, dim1=-2, dim2=-1)).sum(-1)


def step_nll_tensor(f: torch.Tensor, mu: torch.Tensor, sigma_inv: torch.Tensor,
                    logdet_scale: float = 1.0) -> torch.Tensor:
    """Eq. 3 for every observation and every step: ``f (N, F)``, ``mu (T, F)``,
    ``sigma_inv (T, F, F)`` -> ``(N, T)`` in Eq. 3 units.

    ``sigma_inv_t (f - mu_t) = sigma_inv_t f - sigma_inv_t mu_t``: every step's product with
    every observation is one matrix product ``(N, F) @ (F, T F)``, without the ``(N, T, F)``
    differences."""
    T, F = mu.shape
    r = (f @ sigma_inv.reshape(T * F, F).T).reshape(len(f), T, F)  # (N, T, F)
    r = r - (sigma_inv @ mu[:, :, None])[None, :, :, 0]
    return logdet_scale * logdet_tensor(sigma_inv)[None, :] + (r * r).sum(-1)


def aligned_nll_tensor(f: torch.Tensor, t_idx: torch.Tensor, mu: torch.Tensor,
                       sigma_inv: torch.Tensor, logdet_scale: float = 1.0) -> torch.Tensor:
    """Eq. 3 of each observation at its own step ``t_idx (N,)`` (0-based) -> ``(N,)``."""
    diff = f - mu[t_idx]  # (N, F)
    r = torch.einsum("nij,nj->ni", sigma_inv[t_idx], diff)
    return logdet_scale * logdet_tensor(sigma_inv)[t_idx] + (r * r).sum(-1)


# ----------------------------------------------------------------------------- the model


def reaches_last_step(log_trans: np.ndarray, offsets, blocked=(), t_start: int = 0) -> bool:
    """Whether the task's time steps lead from ``t_start`` to the last one avoiding ``blocked``.

    ``log_trans (T, K)``: ``log p(t + offsets[k] | t)``, ``-inf`` where not permitted. With nothing
    blocked it is a task model's invariant (transitions that never reach the last step cannot be
    planned). For the planner, a step whose tool-point target no sampled execution reached does
    not make the task unreachable when the learned transitions can skip it (seen: one sparsely
    aligned step of the pour, tight by accident, at the source container while the bowl was far);
    a run of such steps, as when the bowl is out of the arm's reach, cannot be skipped.
    """
    T = len(log_trans)
    bad = np.zeros(T, dtype=bool)
    bad[np.asarray(blocked, dtype=int)] = True
    ok = np.zeros(T, dtype=bool)  # the robot is at t_start already, reachable or not
    ok[t_start] = True
    for t in range(t_start, T):
        if not ok[t]:
            continue
        for k, lp in zip(offsets, log_trans[t]):
            if k > 0 and t + k < T and np.isfinite(lp) and not bad[t + k]:
                ok[t + k] = True
    return bool(ok[-1])


class TaskModel:
    """A learned task model (plain container of tensors; one dtype/device).

    Attributes
    ----------
    tool : (3,) tool point ``zeta_tool`` in the end-effector frame, metres.
    env : (Z,) weights of the kept landmarks, summing to 1.
    mu : (T, F) per-step feature means.
    sigma_inv : (T, F, F) per-step inverse lower Cholesky factors.
    log_trans : (T, K) ``log p(t + offsets[k] | t)`` (natural log; ``-inf`` where not permitted).
    landmark_names : the kept landmarks, the order of ``env`` and of ``step_nll``'s landmarks.
    all_landmark_names : every landmark of the demonstrations before pruning.
    robot, task : where the model comes from (``task`` may be None).
    options : dict of how it was learned (covariance, tool/env modes, logdet_scale, ...).
    feature_set : 'paper' (Eq. 2, ``F = d + 3``) or 'attitude' (``F = d + 9``, module docstring).
    """

    _TENSORS = ("tool", "env", "mu", "sigma_inv", "log_trans")

    def __init__(self, tool, env, mu, sigma_inv, log_trans, landmark_names, robot: RobotSpec,
                 task: TaskSpec | None = None, all_landmark_names=None, offsets=OFFSETS,
                 covariance: str = "full", logdet_scale: float = 1.0, options: dict | None = None,
                 kin=None, feature_set: str = "paper"):
        self.tool, self.env, self.mu = tool, env, mu
        self.sigma_inv, self.log_trans = sigma_inv, log_trans
        for names in (landmark_names, all_landmark_names):
            check_names(names, "landmark names")
        self.landmark_names = tuple(landmark_names)
        self.all_landmark_names = tuple(all_landmark_names or landmark_names)
        self.robot, self.task = robot, task
        if isinstance(offsets, (str, bytes)) or not all(
                isinstance(k, numbers.Integral) and not isinstance(k, bool) for k in offsets):
            raise ValueError(f"offsets must be whole numbers, got {offsets!r}")
        self.offsets = tuple(int(k) for k in offsets)
        if covariance not in COVARIANCES:
            raise ValueError(f"covariance must be one of {COVARIANCES}, got {covariance!r}")
        self.covariance = covariance
        if feature_set not in FEATURE_SETS:
            raise ValueError(f"feature_set must be one of {FEATURE_SETS}, got {feature_set!r}")
        self.feature_set = feature_set
        self.logdet_scale = float(logdet_scale)
        if options is not None and not isinstance(options, dict):  # dict("x") raised Python's 'dictionary update sequence' error
            raise ValueError(f"TaskModel.options must be a JSON object of how it was learned, got "
                             f"{type(options).__name__} {options!r}"[:200])
        self.options = dict(options or {})
        self._kin = None
        self._validate()
        self.kin = kin  # checked against the robot

    def _validate(self) -> None:
        """Shapes, finiteness and the invariants the planner relies on (a model folder is
        untrusted input: a damaged one must fail here, not deep inside a plan)."""
        for name in self._TENSORS:
            v = getattr(self, name)
            if not isinstance(v, torch.Tensor) or v.dtype not in MODEL_DTYPES:
                raise ValueError(f"TaskModel.{name} must be a float32 or float64 tensor, got "
                                 f"{v.dtype if isinstance(v, torch.Tensor) else type(v).__name__}")
        if self.mu.dim() != 2:
            raise ValueError(f"TaskModel.mu must have shape (T, F), got {tuple(self.mu.shape)}")
        T, F = self.mu.shape
        d = len(self.robot.joint_names)
        for name, shape in (("tool", (3,)), ("env", (len(self.landmark_names),)), ("mu", (T, d + self.n_task_features)),
                            ("sigma_inv", (T, F, F)), ("log_trans", (T, len(self.offsets)))):
            got = tuple(getattr(self, name).shape)
            if got != shape:
                raise ValueError(f"TaskModel.{name} must have shape {shape}, got {got}")
        if T < 2:
            raise ValueError(f"a task model needs at least 2 time steps, got {T}")
        kept, every = self.landmark_names, self.all_landmark_names
        if not all(isinstance(n, str) and n for n in kept + every) or len(set(kept)) != len(kept) \
                or len(set(every)) != len(every):
            raise ValueError(f"landmark names must be distinct non-empty strings, got {list(kept)} "
                             f"(kept) of {list(every)}")
        if not set(self.landmark_names) <= set(self.all_landmark_names):
            raise ValueError(f"kept landmarks {list(self.landmark_names)} are not among all landmarks "
                             f"{list(self.all_landmark_names)}")
        if len(set(self.offsets)) != len(self.offsets) or min(self.offsets) < 0 or 0 not in self.offsets:
            raise ValueError(f"offsets must be distinct, non-negative and include 0, got {list(self.offsets)}")
        for name in ("tool", "env", "mu", "sigma_inv"):
            if not torch.isfinite(getattr(self, name)).all():
                raise ValueError(f"TaskModel.{name} holds NaN or infinite values")
        if torch.isnan(self.log_trans).any() or (self.log_trans > 1e-9).any():
            raise ValueError("TaskModel.log_trans must hold log-probabilities (<= 0, -inf where not permitted)")
        if not reaches_last_step(self.log_trans.detach().cpu().numpy(), self.offsets):
            raise ValueError("TaskModel.log_trans permits no sequence of time steps from the first to the last")
        if abs(float(self.env.sum()) - 1.0) > 1e-4:
            raise ValueError(f"TaskModel.env must sum to 1, got {float(self.env.sum())}")
        if not (torch.diagonal(self.sigma_inv, dim1=-2, dim2=-1) > 0).all():
            raise ValueError("TaskModel.sigma_inv must have a positive diagonal (inverse Cholesky factors)")
        upper = torch.triu(self.sigma_inv, diagonal=1).abs().amax()  # log det is the diagonal's only if triangular
        if float(upper) > 1e-9 * float(self.sigma_inv.abs().amax()):
            raise ValueError(f"TaskModel.sigma_inv must be lower triangular (inverse Cholesky factors), got entries "
                             f"above the diagonal up to {float(upper):.3g}")
        if not (math.isfinite(self.logdet_scale) and self.logdet_scale > 0):
            raise ValueError(f"TaskModel.logdet_scale must be finite and positive, got {self.logdet_scale}")
        big = float(self.mu.detach().abs().amax())  # (1e200 passed, and the IK's SVD raised in a plan)
        if big > MAX_FEATURE:
            raise ValueError(f"TaskModel.mu holds values up to {big:.3g}: its features are joint values and "
                             f"tool positions and attitudes (rad, m), none beyond {MAX_FEATURE:g}")
        L = torch.linalg.inv(self.sigma_inv.detach())  # (T, F, F) Cholesky factors of the covariances
        if not torch.isfinite(L @ L.transpose(-1, -2)).all():  # (a planner's Cholesky raised on them)
            raise ValueError("TaskModel.sigma_inv is too close to singular: its covariances are not finite")

    # -- basic properties
    @property
    def dtype(self) -> torch.dtype:
        return self.mu.dtype

    @property
    def device(self) -> torch.device:
        return self.mu.device

    @property
    def time_steps(self) -> int:
        return int(self.mu.shape[0])

    @property
    def n_features(self) -> int:
        return int(self.mu.shape[1])

    @property
    def n_task_features(self) -> int:
        """Features after the joint angles: 3 (the tool point), 9 with the attitude."""
        return 3 * TASK_VECTORS[self.feature_set]

    @property
    def dof(self) -> int:
        """``d``, the joint angles at the front of the features."""
        return self.n_features - self.n_task_features

    @property
    def tool_features(self) -> slice:
        """Where the tool point sits in the features: ``f[..., tool_features]`` is ``(..., 3)``."""
        return slice(self.dof, self.dof + 3)

    @property
    def trans_cost(self) -> torch.Tensor:
        """``(T, K)`` transition costs in Eq. 3 units: ``-2 log p(t + offsets[k] | t)``."""
        return -2.0 * self.log_trans

    @property
    def covariances(self) -> torch.Tensor:
        """``Sigma_t = (sigma_inv^T sigma_inv)^-1``: ``(T, F, F)``."""
        sigma = torch.linalg.inv(self.sigma_inv)
        return sigma @ sigma.transpose(-1, -2)

    @property
    def kin(self):
        """The ``KinematicModel`` used when ``step_nll`` gets no poses (built on first use)."""
        if self._kin is None:
            from lfd.robot.kinematics import KinematicModel
            self._kin = KinematicModel.from_spec(self.robot, dtype=self.dtype, device=self.device)
        return self._kin

    @kin.setter
    def kin(self, value):
        """Another robot's kinematic model is refused (a plan would be made with the wrong arm);
        one of another dtype or device is converted to the model's (one dtype and device per
        model: a float32 model given the float64 default failed inside the step cost)."""
        if value is not None:
            names = tuple(getattr(value, "joint_names", ()))
            if names != tuple(self.robot.joint_names):
                raise ValueError(f"the kinematic model's joints {list(names)} are not those of the model's robot "
                                 f"{self.robot.name!r}, {list(self.robot.joint_names)}")
            if value.dtype != self.dtype or value.device != self.device:
                value = value.to(self.dtype, self.device)
        self._kin = value

    def to(self, dtype: torch.dtype | None = None, device=None) -> TaskModel:
        """A copy with another dtype and/or device (the kinematic model follows)."""
        device = None if device is None else usable_device(device)
        if dtype is not None:
            _check_dtype(dtype)
        new = object.__new__(TaskModel)
        new.__dict__.update(self.__dict__)
        for k in self._TENSORS:
            setattr(new, k, getattr(self, k).to(dtype=dtype or self.dtype, device=device or self.device))
        new._kin = self._kin.to(dtype, device) if self._kin is not None else None
        return new

    # -- evaluation
    def select_landmarks(self, names, T_world_landmark) -> torch.Tensor:
        """Pick the kept landmarks by name out of a sensed set ``(Z_all, 4, 4)`` -> ``(Z, 4, 4)``."""
        names = list(names)
        missing = [n for n in self.landmark_names if n not in names]
        if missing:
            raise ValueError(f"the task needs landmark(s) {missing}; sensed: {names}")
        T = torch.as_tensor(T_world_landmark, dtype=self.dtype, device=self.device)
        return T[[names.index(n) for n in self.landmark_names]]

    def _landmarks(self, landmarks) -> torch.Tensor:
        if landmarks is None:  # (torch.as_tensor(None) said only 'Could not infer dtype of NoneType')
            raise ValueError(f"landmarks are needed: the poses ({len(self.landmark_names)}, 4, 4) of "
                             f"{list(self.landmark_names)} (select_landmarks picks them by name)")
        T = torch.as_tensor(landmarks, dtype=self.dtype, device=self.device)
        if T.shape != (len(self.landmark_names), 4, 4):
            raise ValueError(f"landmarks must have shape ({len(self.landmark_names)}, 4, 4) for "
                             f"{list(self.landmark_names)}, got {tuple(T.shape)} "
                             f"(use select_landmarks to pick them by name)")
        return T

    def K_virt_inv(self, landmarks) -> torch.Tensor:
        """``K_virt^-1 (4, 4)`` for sensed landmarks ``(Z, 4, 4)`` (kept ones, model order)."""
        return virtual_inverse_tensor(self.env, landmarks_inverse_tensor(self._landmarks(landmarks))[None])[0]

    def features(self, q, T_world_ee=None, landmarks=None) -> torch.Tensor:
        """Eq. 2: ``q (B, d)`` -> ``f (B, F)``; FK computed when ``T_world_ee`` is None."""
        q = torch.as_tensor(q, dtype=self.dtype, device=self.device)
        if q.dim() != 2 or q.shape[1] != self.dof:
            raise ValueError(f"q must have shape (B, {self.dof}), got {tuple(q.shape)}")
        if T_world_ee is None:
            T_world_ee = self.kin.fk(q)
        T_world_ee = torch.as_tensor(T_world_ee, dtype=self.dtype, device=self.device)
        return features_tensor(q, T_world_ee, self.tool, self.K_virt_inv(landmarks), self.feature_set)

    def step_nll(self, q, T_world_ee=None, landmarks=None) -> torch.Tensor:
        """The planner's cost ``(B, d) -> (B, T)``, Eq. 3 units (``s log|Sigma_t| + Mahalanobis^2``).

        ``landmarks``: ``(Z, 4, 4)`` poses of the kept landmarks in ``landmark_names`` order.
        """
        f = self.features(q, T_world_ee, landmarks)
        return step_nll_tensor(f, self.mu, self.sigma_inv, self.logdet_scale)

    # -- persistence
    def config_dict(self) -> dict:
        return {"format": FORMAT, "robot": self.robot.to_dict(),
                "task": self.task.to_dict() if self.task is not None else None,
                "landmark_names": list(self.landmark_names),
                "all_landmark_names": list(self.all_landmark_names),
                "time_steps": self.time_steps, "n_features": self.n_features,
                "offsets": list(self.offsets), "covariance": self.covariance,
                "feature_set": self.feature_set,
                "logdet_scale": self.logdet_scale, "options": self.options}

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {k: getattr(self, k).detach().cpu().clone() for k in self._TENSORS}

    def save(self, out_dir: str | Path) -> None:
        """Write ``model.pt`` (tensors only) and ``config.json`` into ``out_dir``, each atomically."""
        from lfd.learning.checkpoint import atomic_torch_save, atomic_write_text

        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        atomic_torch_save(self.state_dict(), out_dir / "model.pt")
        atomic_write_text(out_dir / "config.json", json.dumps(self.config_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, model_dir: str | Path, dtype: torch.dtype = torch.float64, device="cpu",
             kin=None) -> TaskModel:
        """Rebuild a model written by ``save``, ready to plan: with ``kin``, or the kinematics of its
        robot, built from its URDF in the model's dtype and device when first needed (``kin``), so
        that a model can be loaded and checked (its robot, its landmarks) where that URDF is not.

        Raises
        ------
        ModelFormatError
            missing files, a ``config.json`` that is not ours, tensors of the wrong shape.
        """
        _check_dtype(dtype)  # before the files are read: a dtype refused later was reported as a damaged folder
        device = usable_device(device)
        model_dir = Path(model_dir)
        cfg_path, pt_path = model_dir / "config.json", model_dir / "model.pt"
        for p in (cfg_path, pt_path):
            if not p.is_file():
                raise ModelFormatError(f"{model_dir}: not an lfd task model (missing {p.name})")
        from lfd.learning.checkpoint import read_json_record, refused_load_cause
        cfg = read_json_record(cfg_path, FORMAT, ModelFormatError, "task model config")
        try:
            state = torch.load(pt_path, map_location="cpu", weights_only=True)
        except pickle.UnpicklingError as e:  # weights_only refuses a pickled object that is not tensors
            raise ModelFormatError(f"{pt_path}: cannot be read as a tensor state dict: {refused_load_cause(e)}") from e
        except Exception as e:  # torch raises several kinds for damaged files (a bad zip, a short read)
            raise ModelFormatError(f"{pt_path}: cannot be read as a tensor state dict: damaged or truncated? ({e})") from e
        if not isinstance(state, dict) or set(state) != set(cls._TENSORS):
            raise ModelFormatError(f"{pt_path}: expected tensors {list(cls._TENSORS)}, got "
                                   f"{sorted(state) if isinstance(state, dict) else type(state).__name__}")
        not_real = sorted(k for k, v in state.items() if not isinstance(v, torch.Tensor)
                          or not v.is_floating_point() or v.layout != torch.strided)
        if not_real:
            raise ModelFormatError(f"{pt_path}: {not_real} must be real floating-point (dense) tensors")
        try:
            t = {k: v.to(dtype=dtype, device=device) for k, v in state.items()}
            model = cls(t["tool"], t["env"], t["mu"], t["sigma_inv"], t["log_trans"],
                       landmark_names=cfg["landmark_names"], robot=RobotSpec.from_dict(cfg["robot"]),
                       task=TaskSpec.from_dict(cfg["task"]) if cfg.get("task") else None,
                       all_landmark_names=cfg.get("all_landmark_names"), offsets=cfg["offsets"],
                       covariance=cfg["covariance"], logdet_scale=cfg.get("logdet_scale", 1.0),
                       options=cfg.get("options"), feature_set=cfg.get("feature_set", "paper"))
        except (KeyError, ValueError, TypeError) as e:
            raise ModelFormatError(f"{model_dir}: inconsistent task model ({e})") from e
        model.kin = kin  # the caller's, checked against the model's robot (not a fault of the files)
        said = {"time_steps": model.time_steps, "n_features": model.n_features}
        wrong = {k: (cfg[k], v) for k, v in said.items() if k in cfg and cfg[k] != v}
        if wrong:  # config.json from another model beside this model.pt
            raise ModelFormatError(f"{model_dir}: config.json and model.pt are of different models ("
                                   + ", ".join(f"{k} {a!r} in config.json, {b} in model.pt" for k, (a, b) in wrong.items())
                                   + ")")
        return model
