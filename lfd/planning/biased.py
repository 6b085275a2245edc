"""Biased samples of the task model: where the model wants the robot for given landmarks.

Pure functions of a ``TaskModel`` (with its ``kin``) and the landmark poses, used by
``lfd.planning.task_planner.TaskPlanner`` to grow its roadmap: ``biased_configurations`` draws sampled task
executions as chains of configurations, ``project_to_model`` matches a configuration to a sampled
feature vector in a step's learned metric, and ``chain_edges`` joins consecutive samples of a chain.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from lfd.learning.model import TaskModel, task_features_tensor, task_vectors_tensor
from lfd.robot.ik import IKConfig, solve_ik

__all__ = ["biased_configurations", "chain_edges", "project_to_model"]

IK_BLOCK = 4  # steps of a chain solved together from the block before's last solution


def project_to_model(model: TaskModel, q: torch.Tensor, t, f_target: torch.Tensor,
                     landmarks: torch.Tensor, iters: int = 10, max_step: float = 0.2,
                     batch_collision_fn=None):
    """Configurations near ``q`` whose features are closest to ``f_target`` in step t's metric.

    Minimizes ``|| Sigma_t^-1/2 (f(q) - f_target) ||^2`` (``model.sigma_inv[t]``, Eq. 2 features
    for ``landmarks (Z, 4, 4)``) by damped Gauss-Newton from ``q: (C, d)``; ``f_target: (C, F)``.
    Where IK places the tool point exactly and leaves the joints to a null-space pull, this trades
    tool-point error against joint deviation as the learned covariance does: where the
    demonstrations kept the wrist turned and the tool point loose, so does the result.
    With ``batch_collision_fn`` (``(B, d) -> (B,) bool``, True = in collision), a configuration
    that starts collision-free only takes steps that keep it so: it descends towards the
    demonstrated posture until an obstacle stops it, instead of into the obstacle.
    Returns ``(q (C, d), improved (C,) bool)``; joints stay within their limits.
    """
    kin = model.kin
    d = kin.dof
    W = model.sigma_inv[t].detach()  # (F, F), or (C, F, F) for per-row steps
    W = W.expand(len(q), *W.shape[-2:])  # (C, F, F)
    K = model.K_virt_inv(landmarks).detach()  # (4, 4)
    A = K[:3, :3]
    eye = torch.eye(d, dtype=q.dtype, device=q.device)
    tool = model.tool.detach()

    def residual(q):
        """Residual ``(C, F)`` and its Jacobian ``(C, F, d)`` at ``q``, from one forward pass."""
        J, T_world_ee = kin.jacobian(q, with_pose=True)  # (C, 6, d), (C, 4, 4)
        P = task_vectors_tensor(T_world_ee, tool, model.feature_set)  # (C, k, 3) tool point, axes
        r = (W @ (torch.cat([q, task_features_tensor(P, K)], dim=1) - f_target)[..., None])[..., 0]  # (C, F)
        # d/dq of the tool point: v + w x lever; of an axis a: w x a (J's rows: v, then w)
        lever = P - torch.cat([T_world_ee[:, None, :3, 3], torch.zeros_like(P[:, 1:])], dim=1)  # (C, k, 3)
        J_w = J[:, None, 3:].expand(-1, P.shape[1], -1, -1)  # (C, k, 3, d)
        J_P = torch.cross(J_w, lever[..., None].expand_as(J_w), dim=2)
        J_P[:, 0] += J[:, :3]
        Jr = W @ torch.cat([eye.expand(len(q), d, d), (A @ J_P).reshape(len(q), -1, d)], dim=1)  # (C, F, d)
        return r, Jr

    q = q.detach().clone()
    f_target = f_target.detach()
    r, Jr = residual(q)
    cost0 = cost = (r * r).sum(-1)  # (C,)
    lam = torch.full_like(cost, 1e-2)
    guard = None  # (C,) bool: starts collision-free, must stay so
    if batch_collision_fn is not None and iters > 0:
        guard = ~torch.as_tensor(np.asarray(batch_collision_fn(q.cpu().numpy()), dtype=bool), device=q.device)
    for _ in range(iters):
        H = Jr.transpose(1, 2) @ Jr  # (C, d, d)
        g = (Jr.transpose(1, 2) @ r[..., None])[..., 0]  # (C, d)
        dq = -torch.linalg.solve(H + lam[:, None, None] * (eye + torch.diag_embed(
            torch.diagonal(H, dim1=1, dim2=2))), g)
        dq = dq * (max_step / dq.abs().amax(-1).clamp_min(max_step))[:, None]
        q_new = torch.maximum(torch.minimum(q + dq, kin.upper), kin.lower)
        r_new, Jr_new = residual(q_new)
        cost_new = (r_new * r_new).sum(-1)
        take = cost_new < cost
        if guard is not None:
            check = take & guard
            if bool(check.any()):
                hit = np.asarray(batch_collision_fn(q_new[check].cpu().numpy()), dtype=bool)
                take[check.nonzero()[:, 0][torch.as_tensor(hit, device=q.device)]] = False
        q = torch.where(take[:, None], q_new, q)
        r = torch.where(take[:, None], r_new, r)
        Jr = torch.where(take[:, None, None], Jr_new, Jr)
        cost = torch.where(take, cost_new, cost)
        lam = torch.where(take, lam * 0.3, lam * 10.0)
    return q, cost < cost0


def biased_configurations(model: TaskModel, landmarks: torch.Tensor, n: int,
                          generator: torch.Generator, step_jitter: float = 0.3,
                          project_iters: int = 10, posture_spread: float = 0.0,
                          batch_collision_fn=None, free_posture: bool = False):
    """About ``n`` configurations where the model wants the robot for ``landmarks``.

    ``landmarks``: ``(Z, 4, 4)`` kept landmarks in model order. The samples come as *chains*, one
    sampled task execution each: a chain draws one standard-normal vector ``z`` (plus
    ``step_jitter`` of fresh noise per step) and takes ``f_t = mu_t + sigma_t z`` at every time
    step t, so that consecutive samples of a chain are alike, as consecutive moments of a
    demonstration are. The joint part of ``f_t`` is the null-space posture and the task part,
    mapped into the world through the current ``K_virt``, the target of the tool point; IK solves
    the chain's steps in order, each from the previous step's solution, and ``project_to_model``
    (``project_iters`` Gauss-Newton steps) then moves each solution to the configuration whose
    features best match the sample in the step's learned metric; with ``batch_collision_fn``
    (``(B, d) -> (B,) bool``) a collision-free solution only takes collision-free steps. Consecutive
    configurations of a chain are therefore near each other in joint space and the roadmap gets
    connected corridors through the task, not scattered islands.

    ``free_posture``: arm postures the demonstrations never showed. IK then targets the sample's
    whole tool pose (the tool point where the sample puts it, the gripper turned as the sample's
    joints turn it), each chain's first step from a uniform random configuration and every later
    step from the one before, with no pull towards the sampled joints; the (guarded) projection
    follows. Where an obstacle stands where the demonstrated arm goes (a low lamp shade between
    the shoulder and a far bowl) these still hold the tool as the demonstrator did; the cost
    judges how far they are from the demonstrated posture.

    Returns ``(Q (C*T, d), valid (C*T,) bool, T, reached (C*T,) bool)``, chain-major: sample
    ``c * T + t`` is chain c's configuration at step t; ``valid`` marks samples worth a vertex
    (IK reached the tool-point target within 5 mm, or the projection improved the match);
    ``reached`` the IK successes alone.
    """
    kin = model.kin
    T, F = model.mu.shape
    d = model.dof
    chains = max(1, -(-n // T))
    sigma = torch.linalg.inv(model.sigma_inv)  # (T, F, F) lower Cholesky factors of Sigma_t
    z = torch.randn(chains, 1, F, generator=generator, dtype=model.dtype)
    z = (z + step_jitter * torch.randn(chains, T, F, generator=generator, dtype=model.dtype)).to(model.device)
    f = model.mu[None] + torch.einsum("tij,ctj->cti", sigma, z)  # (C, T, F)
    q_rest = f[..., :d]
    if posture_spread > 0:  # IK starts from and pulls towards another arm posture (the elbow
        # elsewhere); the projection still aims at the sample and settles in that posture's basin
        offset = posture_spread * torch.randn(chains, 1, d, generator=generator, dtype=model.dtype)
        q_rest = q_rest + offset.to(model.device)
    q_rest = torch.maximum(torch.minimum(q_rest, kin.upper), kin.lower)  # (C, T, d)
    T_world_virt = torch.linalg.inv(model.K_virt_inv(landmarks))  # (4, 4)
    p_world = f[..., model.tool_features] @ T_world_virt[:3, :3].T + T_world_virt[:3, 3]  # (C, T, 3)
    weights = torch.tensor([1, 1, 1, 0, 0, 0], dtype=model.dtype, device=model.device)
    T_target = torch.eye(4, dtype=model.dtype, device=model.device).repeat(chains, T, 1, 1)  # (C, T, 4, 4)
    T_target[..., :3, 3] = p_world
    solve: dict[str, Any]  # solve_ik's keyword arguments
    if free_posture:  # the whole pose: the gripper turned as the sampled joints turn it
        T_target[..., :3, :3] = kin.fk(f[..., :d].reshape(-1, d)).reshape(chains, T, 4, 4)[..., :3, :3]
        solve = dict(p_ee_tool=model.tool, config=IKConfig(max_iters=60, min_iters=5, pos_tol=5e-3, rot_tol=0.05))
        seed = kin.sample_uniform(chains, generator=generator).to(model.device)  # (C, d)
    else:
        solve = dict(p_ee_tool=model.tool, weights=weights, config=IKConfig(max_iters=40, min_iters=5, pos_tol=5e-3))
        seed = q_rest[:, 0]
    # the chain's steps in blocks, each block's steps solved together (IK, then the projection)
    # from the last configuration of the block before (the first block from the seed):
    # consecutive configurations stay in one IK branch as when every step starts from the one
    # before, in a few batched calls
    out, ok, hit = [], [], []
    starts = [0] + list(range(1, T, IK_BLOCK))
    for k, t0 in enumerate(starts):
        t1 = starts[k + 1] if k + 1 < len(starts) else T
        b = t1 - t0
        rest: dict[str, Any] = {} if free_posture else {"q_rest": q_rest[:, t0:t1].reshape(-1, d)}
        res = solve_ik(kin, T_target[:, t0:t1].reshape(-1, 4, 4), seed.repeat_interleave(b, dim=0),
                       **solve, **rest)
        steps = torch.arange(t0, t1, device=model.device).repeat(chains)  # (C*b,) each row's step
        q, better = project_to_model(model, res.q, steps, f[:, t0:t1].reshape(-1, F), landmarks,
                                     iters=project_iters, batch_collision_fn=batch_collision_fn)
        out.append(q.reshape(chains, b, d))
        ok.append((res.success | better).reshape(chains, b))
        hit.append(res.success.reshape(chains, b))
        seed = out[-1][:, -1]
    q = torch.cat(out, dim=1).reshape(chains * T, d)
    Q = q.detach().cpu().numpy()  # (C*T, d), chain-major
    valid = torch.cat(ok, dim=1).reshape(-1).cpu().numpy()
    reached = torch.cat(hit, dim=1).reshape(-1).cpu().numpy()
    return Q, valid, T, reached


def chain_edges(valid: np.ndarray, steps_per_chain: int) -> np.ndarray:
    """``(p, 2)`` index pairs of consecutive valid samples within each chain (chain-major order)."""
    idx = np.flatnonzero(valid)
    chain = idx // steps_per_chain
    same = chain[1:] == chain[:-1]
    return np.stack([idx[:-1][same], idx[1:][same]], axis=1)
