"""Damped-least-squares IK (lfd/robot/ik.py) on Baxter's left arm, float64."""

import pytest
import torch

from lfd.robot.ik import IKConfig, rotation_error, solve_ik, tool_point_positions
from lfd.robot.kinematics import KinematicModel


@pytest.fixture(scope="module")
def kin():
    return KinematicModel.from_spec(dtype=torch.float64)


def _inner_configs(kin, n, seed, margin=0.15):
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(n, kin.dof, generator=g, dtype=torch.float64)
    lo, hi = kin.lower + margin, kin.upper - margin
    return lo + u * (hi - lo), g


def test_reaches_fk_targets_from_perturbed_seeds(kin):
    q_true, g = _inner_configs(kin, 64, seed=1)
    T = kin.fk(q_true)
    seed = q_true + 0.15 * torch.randn(q_true.shape, generator=g, dtype=torch.float64)
    r = solve_ik(kin, T, seed)
    assert r.success.float().mean() >= 0.95
    T_sol = kin.fk(r.q)
    ok = r.success
    assert (T_sol[ok, :3, 3] - T[ok, :3, 3]).norm(dim=-1).max() < 1e-4
    assert rotation_error(T[ok, :3, :3], T_sol[ok, :3, :3]).norm(dim=-1).max() < 1e-3


def test_tool_point_target(kin):
    q_true, g = _inner_configs(kin, 32, seed=2)
    p_ee_tool = torch.tensor([0.02, -0.05, 0.2], dtype=torch.float64)
    T = kin.fk(q_true).clone()
    T[:, :3, 3] = tool_point_positions(kin, q_true, p_ee_tool)
    seed = q_true + 0.15 * torch.randn(q_true.shape, generator=g, dtype=torch.float64)
    r = solve_ik(kin, T, seed, p_ee_tool=p_ee_tool)
    assert r.success.float().mean() >= 0.95
    ok = r.success
    assert (tool_point_positions(kin, r.q, p_ee_tool)[ok] - T[ok, :3, 3]).norm(dim=-1).max() < 1e-4


def test_respects_joint_limits(kin):
    # seeds outside the limits and a rest posture beyond them: every iterate stays inside
    q_true, g = _inner_configs(kin, 32, seed=3, margin=0.02)
    T = kin.fk(q_true)
    seed = q_true + 1.0 * torch.randn(q_true.shape, generator=g, dtype=torch.float64)
    assert not bool(kin.within_limits(seed).all())
    r = solve_ik(kin, T, seed, q_rest=kin.upper + 1.0, config=IKConfig(min_iters=30))
    assert bool(kin.within_limits(r.q).all())


def test_position_only_weights(kin):
    q_true, g = _inner_configs(kin, 32, seed=5, margin=0.02)
    T = kin.fk(q_true)
    seed = q_true + 0.3 * torch.randn(q_true.shape, generator=g, dtype=torch.float64)
    r = solve_ik(kin, T, seed, weights=[1, 1, 1, 0, 0, 0])
    assert r.success.float().mean() >= 0.9
    assert float(r.pos_err[r.success].max()) < 1e-4
    assert float(r.rot_err.max()) == 0.0  # rotation not weighted, not reported


def test_nullspace_posture_changes_redundancy(kin):
    q_true, _ = _inner_configs(kin, 1, seed=4, margin=0.5)
    T = kin.fk(q_true)
    cfg = IKConfig(min_iters=60, max_iters=200)
    q_a = solve_ik(kin, T, q_true, q_rest=q_true[0] + 0.4, config=cfg)
    q_b = solve_ik(kin, T, q_true, q_rest=q_true[0] - 0.4, config=cfg)
    assert bool(q_a.success.all() and q_b.success.all())
    assert float((q_a.q - q_b.q).abs().max()) > 0.05  # same pose, different postures


def test_rejects_bad_shapes(kin):
    with pytest.raises(ValueError, match="T_world_target"):
        solve_ik(kin, torch.eye(3), torch.zeros(7))
    with pytest.raises(ValueError, match="q_seed"):
        solve_ik(kin, torch.eye(4), torch.zeros(6))
    with pytest.raises(ValueError, match="weights"):
        solve_ik(kin, torch.eye(4), torch.zeros(7), weights=[1, 1, 1])


def test_a_batch_solves_each_row_as_alone(kin):
    """Rows that converge stop being computed (the batch shrinks to the rest): each row's result,
    error and success equal those of the row solved alone, converged rows and stragglers alike."""
    q_true, g = _inner_configs(kin, 12, seed=5)
    p_ee_tool = torch.tensor([0.0, 0.0, 0.1], dtype=torch.float64)
    T = kin.fk(q_true).clone()
    T[:, :3, 3] = tool_point_positions(kin, q_true, p_ee_tool)
    T[-3:, 0, 3] += 1.5  # out of reach: these run all the iterations
    spread = torch.linspace(0.02, 0.8, 12, dtype=torch.float64)[:, None]  # near seeds converge first
    seed = q_true + spread * torch.randn(q_true.shape, generator=g, dtype=torch.float64)
    cfg = IKConfig(max_iters=30, min_iters=3, pos_tol=1e-3, rot_tol=1e-2)
    batch = solve_ik(kin, T, seed, p_ee_tool=p_ee_tool, config=cfg)
    alone = [solve_ik(kin, T[i], seed[i], p_ee_tool=p_ee_tool, config=cfg) for i in range(12)]
    iters = [r.iters for r in alone]
    assert min(iters) < max(iters) == batch.iters  # rows stopped at different iterations
    assert not bool(batch.success.all()) and bool(batch.success.any())
    for i, r in enumerate(alone):
        torch.testing.assert_close(batch.q[i], r.q[0], rtol=0, atol=1e-10)
        assert bool(batch.success[i]) == bool(r.success[0])
        assert abs(float(batch.pos_err[i] - r.pos_err[0])) < 1e-10
