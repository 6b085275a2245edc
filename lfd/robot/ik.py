"""Batched damped-least-squares inverse kinematics on a ``KinematicModel``.

Targets are poses of a *tool frame*: the end link's frame translated by a tool point
``p_ee_tool`` (3,) given in the end-link frame, orientation unchanged. With
``p_ee_tool = 0`` the target is the end-link pose ``T_world_ee`` itself; with a tool
point the solver places that point at the target position and turns the end link to the
target orientation.

Errors are 6-vectors in the world frame, ``e = (p_target - p_tool, log(R_target R_ee^T))``,
weighted per component by ``weights: (6,)`` or ``(B, 6)`` (``0`` frees a component, e.g.
``(1, 1, 1, 0, 0, 0)`` is position-only IK). One iteration is

    dq = J_w^T (J_w J_w^T + lambda^2 I)^-1 e_w  +  (I - J_w^+ J_w) k (q_rest - q)

with ``J_w = W J`` the weighted tool Jacobian, ``lambda^2`` growing with the error
(Levenberg-Marquardt style) and a null-space pull towards a preferred posture ``q_rest``
(``(d,)`` or per item ``(B, d)``), so that redundancy can be resolved differently per item.
Joint limits are respected by an active set: a joint at a limit whose step points outwards
loses its Jacobian column for that iteration; every iterate is clamped into the limits.
Steps are scaled so that no joint moves more than ``max_step`` rad per iteration, which keeps
solutions near a warm-start seed.

No PyBullet here: the planner reuses this module for biased sampling.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lfd.robot.kinematics import KinematicModel

__all__ = [
    "IKConfig",
    "IKResult",
    "rotation_error",
    "solve_ik",
    "solve_ik_tensor",
    "tool_point_positions",
]


@dataclass(frozen=True)
class IKConfig:
    """Settings of ``solve_ik``.

    Attributes
    ----------
    max_iters : iterations at most.
    min_iters : iterations at least (lets the null-space pull act even when the seed already
        reaches the target).
    damping : base damping ``lambda`` of the least-squares step.
    error_damping : added to ``lambda^2`` times the squared weighted error norm.
    max_step : largest change of any joint in one iteration, rad.
    nullspace_gain : gain ``k`` of the pull towards ``q_rest`` (0 disables it).
    pos_tol : success threshold on the position error, m.
    rot_tol : success threshold on the rotation error, rad.
    """

    max_iters: int = 100
    min_iters: int = 0
    damping: float = 1e-3
    error_damping: float = 1e-2
    max_step: float = 0.3
    nullspace_gain: float = 0.2
    pos_tol: float = 1e-5
    rot_tol: float = 1e-4

    def __post_init__(self):
        if int(self.max_iters) < 1 or int(self.min_iters) < 0 or self.min_iters > self.max_iters:
            raise ValueError(f"IKConfig needs 0 <= min_iters <= max_iters and max_iters >= 1, got "
                             f"min_iters={self.min_iters}, max_iters={self.max_iters}")
        for name in ("damping", "max_step", "pos_tol", "rot_tol"):
            if not getattr(self, name) > 0:
                raise ValueError(f"IKConfig.{name} must be positive, got {getattr(self, name)}")
        if self.nullspace_gain < 0 or self.error_damping < 0:
            raise ValueError("IKConfig.nullspace_gain and error_damping must be >= 0, got "
                             f"{self.nullspace_gain}, {self.error_damping}")


@dataclass(frozen=True)
class IKResult:
    """Result of ``solve_ik``.

    Attributes
    ----------
    q : (B, d) solutions (the last iterate where not successful), within the joint limits.
    success : (B,) bool, position and rotation errors of the weighted components within tolerance.
    pos_err : (B,) position error of the weighted components, m.
    rot_err : (B,) rotation error of the weighted components, rad.
    iters : iterations run.
    """

    q: torch.Tensor
    success: torch.Tensor
    pos_err: torch.Tensor
    rot_err: torch.Tensor
    iters: int


def _quat_from_matrix(R: torch.Tensor) -> torch.Tensor:
    """Unit quaternions (w, x, y, z) with w >= 0 of rotations ``R: (..., 3, 3)``."""
    m = R
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    # four candidate squared magnitudes; pick the largest for numerical robustness
    q2 = torch.stack([1 + tr, 1 + 2 * m[..., 0, 0] - tr, 1 + 2 * m[..., 1, 1] - tr,
                      1 + 2 * m[..., 2, 2] - tr], dim=-1).clamp_min(1e-12)  # (..., 4)
    cands = torch.stack([
        torch.stack([q2[..., 0], m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0],
                     m[..., 1, 0] - m[..., 0, 1]], dim=-1),
        torch.stack([m[..., 2, 1] - m[..., 1, 2], q2[..., 1], m[..., 1, 0] + m[..., 0, 1],
                     m[..., 0, 2] + m[..., 2, 0]], dim=-1),
        torch.stack([m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] + m[..., 0, 1], q2[..., 2],
                     m[..., 2, 1] + m[..., 1, 2]], dim=-1),
        torch.stack([m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0],
                     m[..., 2, 1] + m[..., 1, 2], q2[..., 3]], dim=-1),
    ], dim=-2)  # (..., 4, 4): row i is 2 sqrt(q2_i) * quaternion
    i = q2.argmax(dim=-1)  # (...)
    best = torch.gather(cands, -2, i[..., None, None].expand(*i.shape, 1, 4))[..., 0, :]
    quat = best / (2 * q2.gather(-1, i[..., None]).sqrt())
    quat = quat / quat.norm(dim=-1, keepdim=True)
    return torch.where(quat[..., :1] < 0, -quat, quat)


def rotation_error(R_target: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
    """World-frame rotation vector ``log(R_target R^T)``: ``(..., 3, 3) x2 -> (..., 3)``,
    angle in [0, pi]."""
    quat = _quat_from_matrix(R_target @ R.transpose(-1, -2))  # (..., 4), w >= 0
    v = quat[..., 1:]
    s = v.norm(dim=-1, keepdim=True)
    angle = 2 * torch.atan2(s, quat[..., :1])  # (..., 1)
    # angle / sin(angle / 2) -> 2 as s -> 0
    scale = torch.where(s > 1e-9, angle / s.clamp_min(1e-12), torch.full_like(s, 2.0))
    return v * scale


def tool_point_positions(kin: KinematicModel, q, p_ee_tool) -> torch.Tensor:
    """World positions of the tool point ``p_ee_tool: (3,)`` or ``(B, 3)`` for ``q: (B, d)`` -> (B, 3)."""
    T_world_ee = kin.fk(q).reshape(-1, 4, 4)
    p = torch.as_tensor(p_ee_tool, dtype=kin.dtype, device=kin.device)
    return T_world_ee[:, :3, 3] + (T_world_ee[:, :3, :3] @ p.expand(T_world_ee.shape[0], 3)[..., None])[..., 0]


def _skew(v: torch.Tensor) -> torch.Tensor:
    """``(B, 3) -> (B, 3, 3)`` with ``skew(v) @ w = v x w``."""
    z = torch.zeros_like(v[:, 0])
    return torch.stack([torch.stack([z, -v[:, 2], v[:, 1]], -1),
                        torch.stack([v[:, 2], z, -v[:, 0]], -1),
                        torch.stack([-v[:, 1], v[:, 0], z], -1)], dim=-2)


def _tool_errors(kin: KinematicModel, q: torch.Tensor, p_ee_tool: torch.Tensor | None,
                 T_world_target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Pose errors ``(b, 6)`` (position, rotation; world frame) of the tool at ``q (b, d)``
    against ``T_world_target (b, 4, 4)``, and the tool's Jacobians ``(b, 6, d)``; ``p_ee_tool
    (b, 3)`` the tool points in the end-link frame, or None for the end link itself."""
    J, T_world_ee = kin.jacobian(q, with_pose=True)  # (b, 6, d), (b, 4, 4)
    R = T_world_ee[:, :3, :3]
    if p_ee_tool is not None:
        r = (R @ p_ee_tool[..., None])[..., 0]  # (b, 3) lever arm in the world frame
        p = T_world_ee[:, :3, 3] + r
        J = torch.cat([J[:, :3] - _skew(r) @ J[:, 3:], J[:, 3:]], dim=1)  # v_tool = v_ee + w x r
    else:
        p = T_world_ee[:, :3, 3]
    e = torch.cat([T_world_target[:, :3, 3] - p, rotation_error(T_world_target[:, :3, :3], R)], dim=-1)
    return e, J


def _dls_step(kin: KinematicModel, q: torch.Tensor, e: torch.Tensor, J: torch.Tensor, w: torch.Tensor,
              q_rest: torch.Tensor, config: IKConfig) -> torch.Tensor:
    """One damped least-squares step ``q (b, d) -> (b, d)`` from errors ``e (b, 6)`` weighted by
    ``w (b, 6)``, Jacobians ``J (b, 6, d)``, with a pull towards ``q_rest (b, d)`` in the exact
    null space of the constraining rows; joints at a limit that the step would push further
    are taken out of the Jacobian; the step is clamped to ``config.max_step`` and the limits."""
    b, d = q.shape
    lower, upper = kin.lower, kin.upper
    eye6 = torch.eye(6, dtype=q.dtype, device=q.device)
    eye_d = torch.eye(d, dtype=q.dtype, device=q.device)
    ew = e * w  # (b, 6)
    Jw = J * w[..., None]  # (b, 6, d)
    lam2 = config.damping ** 2 + config.error_damping * (ew * ew).sum(-1)  # (b,)
    null_pull = config.nullspace_gain * (q_rest - q)  # (b, d)
    null_pull = torch.where(((q <= lower + 1e-9) & (null_pull < 0))
                            | ((q >= upper - 1e-9) & (null_pull > 0)), 0.0, null_pull)
    free = torch.ones_like(q)
    for _ in range(2):  # second pass with saturated joints removed from the Jacobian
        Jf = Jw * free[:, None, :]
        A = Jf @ Jf.transpose(1, 2) + lam2[:, None, None] * eye6  # (b, 6, 6)
        Jpinv = Jf.transpose(1, 2) @ torch.linalg.inv(A)  # (b, d, 6)
        # exact projector onto the null space of the rows that constrain (not the damped one,
        # whose leak would fight the task near singularities)
        _, S, Vh = torch.linalg.svd(Jf, full_matrices=True)  # S: (b, 6), Vh: (b, d, d)
        rank_on = (S > 1e-6 * S[:, :1].clamp_min(1e-12)).to(q.dtype)  # (b, 6)
        rank_on = torch.cat([rank_on, rank_on.new_zeros(b, d - rank_on.shape[1])], dim=1)
        V = Vh.transpose(1, 2)
        N = eye_d - (V * rank_on[:, None, :]) @ Vh  # (b, d, d)
        N = N * free[:, None, :] * free[:, :, None]
        dq = (Jpinv @ ew[..., None])[..., 0] + (N @ null_pull[..., None])[..., 0]  # (b, d)
        pushing = ((q <= lower + 1e-9) & (dq < 0)) | ((q >= upper - 1e-9) & (dq > 0))
        if not bool((pushing & (free > 0)).any()):
            break
        free = free * (~pushing).to(q.dtype)
    dq = dq * free
    scale = (config.max_step / dq.abs().amax(dim=-1).clamp_min(1e-12)).clamp(max=1.0)  # (b,)
    return torch.minimum(torch.maximum(q + dq * scale[:, None], lower), upper)


def solve_ik_tensor(kin: KinematicModel, T_world_target: torch.Tensor, q_seed: torch.Tensor,
                    p_ee_tool: torch.Tensor | None = None, weights: torch.Tensor | None = None,
                    q_rest: torch.Tensor | None = None, config: IKConfig = IKConfig()) -> IKResult:
    """Kernel of ``solve_ik``: every input already a tensor of ``kin``'s dtype and device.

    T_world_target : (B, 4, 4) target poses of the tool frame.
    q_seed : (B, d) warm starts (clamped into the limits first).
    p_ee_tool : (B, 3) tool points in the end-link frame, or None for the end link itself.
    weights : (B, 6) error weights (position xyz, rotation xyz, world frame), or None for ones.
    q_rest : (B, d) preferred postures for the null-space pull, or None for the seeds.
    Rows that meet the tolerances (after ``config.min_iters``) stop; only the others go on.
    """
    B = q_seed.shape[0]
    q = torch.minimum(torch.maximum(q_seed, kin.lower), kin.upper).clone()  # (B, d), never the caller's
    if q_rest is None:
        q_rest = q.clone()
    w = torch.ones(B, 6, dtype=q.dtype, device=q.device) if weights is None else weights  # (B, 6)
    pos_on = (w[:, :3] > 0).to(q.dtype)
    rot_on = (w[:, 3:] > 0).to(q.dtype)

    def errors(q_rows, rows):
        return _tool_errors(kin, q_rows, None if p_ee_tool is None else p_ee_tool[rows], T_world_target[rows])

    rows = torch.arange(B, device=q.device)
    e, J = errors(q, rows)
    e_all = e.clone()  # (B, 6) every row's latest error
    it = 0
    for it in range(1, config.max_iters + 1):
        if it > config.min_iters:
            pos_err = (e[:, :3] * pos_on[rows]).norm(dim=-1)
            rot_err = (e[:, 3:] * rot_on[rows]).norm(dim=-1)
            going = ~((pos_err <= config.pos_tol) & (rot_err <= config.rot_tol))
            if not bool(going.any()):
                it -= 1
                break
            if not bool(going.all()):
                rows, e, J = rows[going], e[going], J[going]
        q_rows = _dls_step(kin, q[rows], e, J, w[rows], q_rest[rows], config)
        q[rows] = q_rows
        e, J = errors(q_rows, rows)
        e_all[rows] = e
    e = e_all
    pos_err = (e[:, :3] * pos_on).norm(dim=-1)
    rot_err = (e[:, 3:] * rot_on).norm(dim=-1)
    success = (pos_err <= config.pos_tol) & (rot_err <= config.rot_tol)
    return IKResult(q=q, success=success, pos_err=pos_err, rot_err=rot_err, iters=it)


def solve_ik(kin: KinematicModel, T_world_target, q_seed, p_ee_tool=None, weights=None,
             q_rest=None, config: IKConfig | None = None) -> IKResult:
    """Inverse kinematics of a batch of tool-frame targets.

    Parameters
    ----------
    kin : the arm.
    T_world_target : shape (B, 4, 4) or (4, 4); target poses of the tool frame (orientation of
        the end link, origin at the tool point). Anything ``torch.as_tensor`` accepts.
    q_seed : shape (B, d) or (d,); warm starts, broadcast over the batch.
    p_ee_tool : shape (3,) or (B, 3), metres in the end-link frame; None targets the end link.
    weights : shape (6,) or (B, 6), error weights (x, y, z, rx, ry, rz in the world frame);
        zero frees a component. None weights all six by one.
    q_rest : shape (d,) or (B, d), preferred postures of the null-space pull; None keeps the seeds.
    config : ``IKConfig``.

    Returns
    -------
    IKResult, batch-first (a batch of one for a single target).

    Raises
    ------
    ValueError
        inputs of the wrong shape (the message quotes what arrived).
    """
    config = config or IKConfig()
    as_t = lambda x: torch.as_tensor(x, dtype=kin.dtype, device=kin.device)
    T = as_t(T_world_target)
    if T.shape[-2:] != (4, 4) or T.dim() not in (2, 3):
        raise ValueError(f"T_world_target must have shape (B, 4, 4) or (4, 4), got {tuple(T.shape)}")
    T = T.reshape(-1, 4, 4)
    B, d = T.shape[0], kin.dof

    def batch(x, name, width):
        x = as_t(x)
        if x.shape[-1] != width or x.dim() not in (1, 2) or (x.dim() == 2 and x.shape[0] not in (1, B)):
            raise ValueError(f"{name} must have shape ({width},) or ({B}, {width}), got {tuple(x.shape)}")
        return x.reshape(-1, width).expand(B, width).clone()

    q0 = batch(q_seed, "q_seed", d)
    if B == 1 and q0.shape[0] != 1:
        raise ValueError(f"q_seed batch {q0.shape[0]} does not match the targets' batch {B}")
    p = None if p_ee_tool is None else batch(p_ee_tool, "p_ee_tool", 3)
    w = None if weights is None else batch(weights, "weights", 6)
    if w is not None and bool((w < 0).any()):
        raise ValueError("weights must be non-negative")
    qr = None if q_rest is None else batch(q_rest, "q_rest", d)
    return solve_ik_tensor(kin, T, q0, p_ee_tool=p, weights=w, q_rest=qr, config=config)
