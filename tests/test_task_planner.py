"""TaskPlanner glue, its step cost, chain edges (no simulator needed; plan timing: test_timing.py)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from lfd.robot.kinematics import KinematicModel
from lfd.learning.model import TaskModel, logdet_tensor
from lfd.robot.robots import BAXTER_LEFT
from lfd.planning.stepcost import ModelStepCost
from lfd.planning.biased import chain_edges
from lfd.planning.edgestore import EdgeStore
from lfd.learning.tasks import POWDER
from lfd.planning.task_planner import TaskPlanner, TaskPlannerSettings


@pytest.fixture(scope="module")
def kin():
    return KinematicModel.from_spec(dtype=torch.float64)


def _model(kin, T=6, feature_set="paper"):
    """A hand-made model: the tool point rides a line towards the landmark over T steps (with
    the attitude: the gripper's axes held along the world's x and y, loosely)."""
    g = torch.Generator().manual_seed(0)
    q_mid = (kin.lower + kin.upper) / 2
    q_mid = torch.where(torch.isfinite(q_mid), q_mid, torch.zeros_like(q_mid))
    F = 10 if feature_set == "paper" else 16
    mu = torch.zeros(T, F, dtype=torch.float64)
    mu[:, :7] = q_mid + 0.05 * torch.randn(T, 7, generator=g, dtype=torch.float64)
    mu[:, 7:10] = torch.linspace(0.4, 0.1, T, dtype=torch.float64)[:, None] * torch.tensor([1.0, 0.0, 1.0])
    sd = [0.8] * 7 + [0.2] * 3
    if feature_set == "attitude":
        mu[:, 10], mu[:, 14] = 1.0, 1.0
        sd += [0.5] * 6
    sigma_inv = torch.diag_embed(1 / torch.tensor(sd, dtype=torch.float64)).repeat(T, 1, 1)
    log_trans = torch.log(torch.tensor([0.5, 0.4, 0.1], dtype=torch.float64)).repeat(T, 1)
    log_trans[-1] = torch.tensor([0.0, -math.inf, -math.inf])
    log_trans[-2, 2] = -math.inf
    return TaskModel(torch.tensor([0.0, 0.0, 0.1], dtype=torch.float64), torch.ones(1, dtype=torch.float64),
                     mu, sigma_inv, log_trans, ["bowl"], BAXTER_LEFT, task=POWDER, kin=kin, feature_set=feature_set)


def test_chain_edges_join_consecutive_valid_samples():
    valid = np.array([1, 1, 0, 1, 1, 1, 0, 0], dtype=bool)  # two chains of 4 steps
    pairs = chain_edges(valid, 4)
    assert pairs.tolist() == [[0, 1], [1, 3], [4, 5]]


def test_task_planner_plans_and_reports_missing_landmark(kin):
    model = _model(kin)
    free = lambda q: False  # noqa: E731
    planner = TaskPlanner(model, free, lambda a, b: False,
                          settings=TaskPlannerSettings(n_vertices=120, seed=0))
    assert planner.plan(np.zeros(7), 0).status == "missing_landmark"
    bowl = np.eye(4)[None]
    bowl[0, :3, 3] = [0.7, 0.4, -0.1]
    planner.update_landmarks(["marker", "bowl"], np.concatenate([np.eye(4)[None], bowl]))
    q0 = model.mu[0, :7].numpy()
    res = planner.plan(q0, 0)
    assert res.ok, res.message
    assert res.time_steps[0] == 0 and res.time_steps[-1] == model.time_steps - 1
    assert np.all(np.diff(res.time_steps) >= 0)
    planner.update_landmarks(["marker"], np.eye(4)[None])  # the bowl is no longer sensed
    assert planner.plan(q0, 0).status == "missing_landmark"


def test_landmark_poses_of_another_shape_or_not_rigid_are_refused_before_the_build(kin):
    """A tracker's poses in another convention (a scaled rotation, a bottom row that is not
    0 0 0 1, one pose short) raise a ValueError naming the problem, and build nothing; a NaN
    pose is a landmark not sensed, not an error."""
    planner = TaskPlanner(_model(kin), lambda q: False, lambda a, b: False,
                          settings=TaskPlannerSettings(n_vertices=20, seed=0))
    bowl = np.eye(4)
    bowl[:3, 3] = [0.7, 0.4, -0.1]
    scaled, skewed = bowl.copy(), bowl.copy()
    scaled[:3, :3] *= 1.001  # a rotation 0.1% too long (a scale left in the transform)
    skewed[3, 0] = 0.01
    for poses, fragment in [(np.stack([np.eye(4), scaled]), "'bowl' is not a rigid transform"),
                            (np.stack([skewed, bowl]), "'marker' is not a rigid transform"),
                            (bowl[None], r"shape \(2, 4, 4\) for the 2 names, got \(1, 4, 4\)"),
                            (np.stack([np.eye(4), bowl])[:, :3], r"got \(2, 3, 4\)")]:
        with pytest.raises(ValueError, match=fragment):
            planner.update_landmarks(["marker", "bowl"], poses)
        assert planner.roadmap is None
    unsensed = np.stack([np.eye(4), np.full((4, 4), np.nan)])
    planner.update_landmarks(["marker", "bowl"], unsensed)
    assert planner.plan(np.zeros(7), 0).status == "missing_landmark"


def _pose(rotvec, position):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = position
    return T


def _random_cov_model(kin, feature_set: str, blocks: bool | str) -> TaskModel:
    """``_model``'s means with random covariances, full (False), in the learner's blocks (True:
    joints, tool point, attitude) or with one task block (``'task'``: joints apart, the tool
    point and the attitude together, the learner's final Gaussians), two landmarks mixed 0.3 /
    0.7, ``s = 0.6``."""
    base = _model(kin, feature_set=feature_set)
    T, F = base.mu.shape
    g = torch.Generator().manual_seed(5)
    L = torch.tril(0.3 * torch.randn(T, F, F, generator=g, dtype=torch.float64), -1)
    if blocks:  # joints, tool point, attitude: the learner's default 'block' covariance
        group = torch.tensor([0] * 7 + [1] * 3 + [1 if blocks == "task" else 2] * 6)[:F]
        L = L * (group[:, None] == group[None, :])
    sigma_inv = L + torch.diag_embed(torch.exp(0.5 * torch.randn(T, F, generator=g, dtype=torch.float64)))
    return TaskModel(torch.tensor([0.02, -0.01, 0.1], dtype=torch.float64),
                     torch.tensor([0.3, 0.7], dtype=torch.float64), base.mu, sigma_inv, base.log_trans,
                     ["bowl", "cup"], BAXTER_LEFT, task=POWDER, logdet_scale=0.6, kin=kin, feature_set=feature_set)


@pytest.mark.parametrize("feature_set,blocks", [("paper", False), ("attitude", False), ("attitude", True),
                                                ("attitude", "task")])
def test_step_cost_is_the_models_mahalanobis_term(kin, feature_set, blocks):
    """The planner's step cost is ``ModelStepCost``: per configuration and step, ``step_nll`` less
    ``s log|Sigma_t|`` (full or block covariances, s != 1, two rotated landmarks); prepared once,
    it follows the landmarks when they move."""
    model = _random_cov_model(kin, feature_set, blocks)
    T, F = model.mu.shape
    planner = TaskPlanner(model, lambda q: False, lambda a, b: False,
                          settings=TaskPlannerSettings(n_vertices=60, seed=0))
    names = ["marker", "cup", "bowl"]
    poses = np.stack([np.eye(4), _pose([0.0, 0.0, 0.8], [0.6, -0.2, 0.0]), _pose([0.3, -0.2, 0.1], [0.7, 0.4, -0.1])])
    planner.update_landmarks(names, poses)
    assert planner.plan(model.mu[0, :7].numpy(), 0).ok
    cost = planner.planner.edges.step_cost
    assert isinstance(cost, ModelStepCost) and cost.model is model
    Q = np.concatenate([planner.roadmap.vertices[:20],
                        kin.sample_uniform(30, generator=torch.Generator().manual_seed(6)).numpy()])
    parts = cost.prepare(Q)
    # a block covariance keeps no per-configuration beta' (it is one (T, 3k) for all), a full one does
    assert [tuple(p.shape) for p in parts[1:]] == [(len(Q), T)] + ([] if blocks else [(len(Q), T, F - 7)])
    floor = model.logdet_scale * logdet_tensor(model.sigma_inv)  # (T,) s log|Sigma_t|
    assert float(floor.abs().min()) > 0.1  # the floor left out is not zero
    moved = poses.copy()
    moved[2] = _pose([0.0, 0.5, -0.2], [0.5, 0.1, 0.2])
    got = []
    for sensed in (poses, moved):
        landmarks = model.select_landmarks(names, sensed)
        Qt = torch.as_tensor(Q)
        want = (model.step_nll(Qt, kin.fk(Qt), landmarks) - floor).numpy()  # (N, T)
        got.append(cost.evaluate(parts, landmarks))
        assert got[-1].shape == (len(Q), T) and (want > 1.0).any()
        np.testing.assert_allclose(got[-1], want, rtol=1e-9, atol=1e-9 * np.abs(want).max())
    assert np.abs(got[1] - got[0]).max() > 1.0  # the move changes the costs
    planner.update_landmarks(names, moved)
    torch.testing.assert_close(planner._landmarks, model.select_landmarks(names, moved))


class _NodeByNode:
    """A step cost without ``prepare_sums``: the edge store evaluates every quadrature node."""

    def __init__(self, cost):
        self.cost, self.T = cost, cost.T

    def prepare(self, Q):
        return self.cost.prepare(Q)

    def evaluate(self, parts, landmarks):
        return self.cost.evaluate(parts, landmarks)


class _CountingSums(_NodeByNode):
    """A step cost that sums (delegating to ``cost``) and counts the summed evaluations."""

    calls = 0

    def prepare_sums(self, Q, counts):
        return self.cost.prepare_sums(Q, counts)

    def evaluate_sums(self, parts, landmarks):
        self.calls += 1
        return self.cost.evaluate_sums(parts, landmarks)


@pytest.mark.parametrize("feature_set,blocks", [("paper", True), ("attitude", True), ("attitude", "task"),
                                                ("attitude", False)])
def test_edge_costs_from_summed_parts_equal_the_sums_over_the_nodes(kin, feature_set, blocks):
    """``prepare_sums``/``evaluate_sums`` (an edge's cost from its nodes' moments, one evaluation
    per edge) give each run's summed ``evaluate``, before and after a landmark move, runs of 0
    rows included; a full covariance couples joints and task features and declines (None), and
    the planner's edge costs then come from every node. The edge store's costs equal those
    computed node by node either way."""
    model = _random_cov_model(kin, feature_set, blocks)
    cost = ModelStepCost(model, max_batch=7)  # several batches, runs straddling them
    rng = np.random.default_rng(3)
    counts = rng.integers(0, 5, 40)
    counts[:3] = [0, 1, 0]
    Q = kin.sample_uniform(int(counts.sum()), generator=torch.Generator().manual_seed(4)).numpy()
    names = ["cup", "bowl"]
    poses = np.stack([_pose([0.0, 0.0, 0.8], [0.6, -0.2, 0.0]), _pose([0.3, -0.2, 0.1], [0.7, 0.4, -0.1])])
    moved = poses.copy()
    moved[1] = _pose([0.0, 0.5, -0.2], [0.5, 0.1, 0.2])
    summed = cost.prepare_sums(Q, counts)
    assert (summed is None) == (not blocks)
    if summed is not None:
        parts = cost.prepare(Q)
        ends = np.cumsum(counts)
        for sensed in (poses, moved):
            landmarks = model.select_landmarks(names, sensed)
            per_node = cost.evaluate(parts, landmarks)  # (N, T)
            want = np.stack([per_node[e - c:e].sum(0) for e, c in zip(ends, counts)])
            got = cost.evaluate_sums(summed, landmarks)
            assert want.max() > 10.0 and (want[counts == 0] == 0).all()
            np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-10 * want.max())
    planner = TaskPlanner(model, lambda q: False, lambda a, b: False,
                          settings=TaskPlannerSettings(n_vertices=60, seed=0))
    planner.update_landmarks(names, moved)
    assert planner.plan(model.mu[0, :7].numpy(), 0).ok
    E = planner.planner.edges
    assert (E.m > 2).sum() > 10  # edges with several interior nodes
    counted = _CountingSums(E.step_cost)
    stores = [EdgeStore(planner.roadmap, c, E.stay, E.dt, E.vmax, E.quad_dt) for c in (counted, _NodeByNode(E.step_cost))]
    for store in stores:
        store.invalidate(landmarks=model.select_landmarks(names, moved))
    (ell, W), (ell_n, W_n) = (store.costs() for store in stores)
    assert counted.calls == (1 if blocks else 0)  # the summed path was taken when the cost can sum
    np.testing.assert_array_equal(ell, ell_n)
    np.testing.assert_allclose(W, W_n, rtol=1e-10, atol=1e-10 * np.abs(W_n[np.isfinite(W_n)]).max())


@pytest.mark.parametrize("dtype,feature_set", [(torch.float64, "paper"), (torch.float32, "paper"),
                                               (torch.float64, "attitude")])
def test_project_to_model_recovers_the_configuration_of_reachable_features(dtype, feature_set):
    """Features of a known configuration as the target: Gauss-Newton from a perturbed start
    returns to it (the joint features make the minimum unique), never leaving the limits
    (with the attitude features, their Jacobian must be right for the same convergence)."""
    from lfd.planning.biased import project_to_model
    kin = KinematicModel.from_spec(dtype=dtype)
    model = _model(KinematicModel.from_spec(dtype=torch.float64), feature_set=feature_set).to(dtype=dtype)
    model.kin = kin
    g = torch.Generator().manual_seed(3)
    landmarks = torch.eye(4, dtype=dtype)[None].clone()
    landmarks[0, :3, 3] = torch.tensor([0.7, 0.2, -0.1], dtype=dtype)
    q_true = model.mu[2, :7].detach() + 0.2 * torch.randn(8, 7, generator=g, dtype=dtype)
    q_true = torch.maximum(torch.minimum(q_true, kin.upper - 0.3), kin.lower + 0.3)  # (8, 7)
    f_true = model.features(q_true, landmarks=landmarks).detach()  # (8, F)
    q0 = q_true + 0.15 * torch.randn(8, 7, generator=g, dtype=dtype)
    q, improved = project_to_model(model, q0, 2, f_true, landmarks, iters=25)
    assert bool(improved.all())
    tol = 1e-6 if dtype == torch.float64 else 2e-3
    assert float((q - q_true).abs().max()) < tol
    assert bool(kin.within_limits(q).all())


def test_project_to_model_trades_tool_error_for_joints_as_the_covariance_says():
    """A target whose tool point the joints cannot give: with a loose tool-point variance the
    joints stay near their target, with a tight one the tool point is matched instead."""
    from lfd.planning.biased import project_to_model
    kin = KinematicModel.from_spec(dtype=torch.float64)
    landmarks = torch.eye(4, dtype=torch.float64)[None]
    errs = {}
    for name, s_tool in (("loose", 1.0), ("tight", 0.001)):
        model = _model(kin)
        model.sigma_inv = torch.diag_embed(torch.cat([torch.full((7,), 1 / 0.1), torch.full((3,), 1 / s_tool)])
                                           ).to(torch.float64).repeat(model.mu.shape[0], 1, 1)
        model.kin = kin
        q_t = model.mu[:1, :7].detach()
        f_t = model.features(q_t, landmarks=landmarks).detach()
        f_t[:, 7:] += torch.tensor([0.05, -0.05, 0.05], dtype=torch.float64)  # move the tool target 8.7 cm
        q, _ = project_to_model(model, q_t.clone(), 0, f_t, landmarks, iters=30)
        x = model.features(q, landmarks=landmarks).detach()[:, 7:]
        errs[name] = (float((x - f_t[:, 7:]).norm()), float((q - q_t).norm()))
    assert errs["tight"][0] < 0.005 < errs["loose"][0]      # tight: the tool point reaches its target
    assert errs["loose"][1] < 0.02 < errs["tight"][1]       # loose: the joints barely move


def test_region_samples_follow_the_inflated_joint_gaussians(kin):
    """Region vertices are N(mu_t, inflation^2 Sigma_t) over the joints: with one posture for all
    steps and sigma 0.05 rad, the samples' mean is that posture and their spread 2 x 0.05."""
    model = _model(kin)
    model.mu = model.mu.clone()
    model.mu[:, :7] = model.mu[0, :7]
    model.sigma_inv = torch.diag_embed(torch.cat([torch.full((7,), 1 / 0.05), torch.full((3,), 1 / 0.2)])
                                       ).to(torch.float64).repeat(model.mu.shape[0], 1, 1)
    planner = TaskPlanner(model, lambda q: False, lambda a, b: False,
                          settings=TaskPlannerSettings(n_vertices=50, region_inflation=2.0))
    Q = planner.region_samples(20000)
    assert Q.shape == (20000, 7)
    assert np.abs(Q.mean(0) - model.mu[0, :7].numpy()).max() < 0.005
    assert np.abs(Q.std(0) - 0.1).max() < 0.005
    assert np.all(Q >= kin.lower.numpy()) and np.all(Q <= kin.upper.numpy())
    with pytest.raises(ValueError, match="region_fraction"):
        TaskPlannerSettings(region_fraction=1.5)
    with pytest.raises(ValueError, match="posture_share"):
        TaskPlannerSettings(posture_share=-0.1)
    untimed = _model(kin)
    untimed.task = None  # a model learned without a task.json has no time step to plan with
    with pytest.raises(ValueError, match="the model names no task"):
        TaskPlanner(untimed, lambda q: False, lambda a, b: False)
    assert TaskPlanner(untimed, lambda q: False, lambda a, b: False, dt=0.05).dt == 0.05
    with pytest.raises(ValueError, match="differs from the model's task 'powder', 0.1 s"):
        TaskPlanner(_model(kin), lambda q: False, lambda a, b: False, dt=0.05)
    for bad in ({"max_vertices": 1}, {"n_vertices": 100, "max_vertices": 50}):
        with pytest.raises(ValueError, match="max_vertices must be None or at least n_vertices"):
            TaskPlannerSettings(**bad)
    for seed in (-1, 2**63, 1.5, True):
        with pytest.raises(ValueError, match="seed must be a whole number"):
            TaskPlannerSettings(seed=seed)


def _tight_model(kin):
    """``_model`` with the tool point held within 2 cm of its mean: every step is task-relevant
    (``lfd.planning.growth.TASK_STEP_SD``)."""
    model = _model(kin)
    model.sigma_inv = torch.diag_embed(torch.cat([torch.full((7,), 1 / 0.8), torch.full((3,), 1 / 0.02)])
                                       ).to(torch.float64).repeat(model.mu.shape[0], 1, 1)
    return model


def test_a_landmark_out_of_reach_gives_unreachable_then_ok_when_back(kin):
    """A bowl 3 m away: no sampled execution reaches its tool-point targets, so the planner says
    'unreachable' instead of returning some path far from the bowl; moved back, it plans again
    (the verdict is kept per landmark place, no resampling when the bowl returns)."""
    model = _tight_model(kin)
    planner = TaskPlanner(model, lambda q: False, lambda a, b: False,
                          settings=TaskPlannerSettings(n_vertices=150, seed=0))
    near, far = np.eye(4)[None].copy(), np.eye(4)[None].copy()
    near[0, :3, 3] = [0.7, 0.4, -0.1]
    far[0, :3, 3] = [0.2, 3.0, 0.0]
    q0 = model.mu[0, :7].numpy()
    planner.update_landmarks(["bowl"], near)
    assert planner.plan(q0, 0).ok
    planner.update_landmarks(["bowl"], far)
    res = planner.plan(q0, 0)
    assert res.status == "unreachable" and "out of" not in res.message and "time step" in res.message
    n = planner.roadmap.n
    planner.update_landmarks(["bowl"], near)
    assert planner.plan(q0, 0).ok and planner.roadmap.n == n
    # without growth (as a caller that grows later does): the verdict is the one remembered for
    # the place, not the one of the place the bowl left (a bowl back in reach was 'unreachable')
    planner.update_landmarks(["bowl"], far, grow=False)
    assert planner.plan(q0, 0).status == "unreachable"
    planner.update_landmarks(["bowl"], near, grow=False)
    assert planner.plan(q0, 0).ok and planner.roadmap.n == n


@pytest.mark.parametrize("how", ["appears", "drifts"])
def test_a_landmark_first_sensed_after_the_build_or_drifting_slowly_is_an_obstacle(kin, how):
    """A vase put on the first plan's path: sensed for the first time after the build ('appears'),
    or lowered onto it 4 mm per update from 1.2 m above ('drifts', each update under the 5 mm move
    tolerance). The re-plan avoids it: edges checked free before were checked again. (Both gave
    plans through the vase: a landmark without an earlier position, and each small step, were not
    reported as a move.)"""
    model = _tight_model(kin)
    radius = 0.04
    vase = {"at": None}

    def hit(q):  # the vase's name when a keypoint of q (link origins, tool point) is within radius of it
        if vase["at"] is None:
            return ""
        return "vase" if np.linalg.norm(planner.keypoints(np.asarray(q)[None])[0] - vase["at"], axis=1).min() < radius \
            else ""

    def seg(a, b):
        return any(hit(a + (b - a) * s) for s in np.linspace(0, 1, 41))

    planner = TaskPlanner(model, hit, seg, settings=TaskPlannerSettings(n_vertices=150, seed=0))
    bowl = np.eye(4)
    bowl[:3, 3] = [0.7, 0.4, -0.1]
    q0 = model.mu[0, :7].numpy()

    def sense(at):
        vase["at"] = at
        pose = np.eye(4)
        pose[:3, 3] = at
        planner.update_landmarks(["bowl", "vase"], np.stack([bowl, pose]), grow=False)

    if how == "appears":
        planner.update_landmarks(["bowl"], bowl[None])
    else:
        sense(np.array([3.0, 3.0, 3.0]))  # sensed at the build, far away
    first = planner.plan(q0, 0)
    P = first.configurations
    moving = [i for i in range(1, len(P) - 1) if first.vertices[i] >= 0 and first.vertices[i + 1] >= 0
              and np.abs(P[i + 1] - P[i]).max() > 0]  # the roadmap edges the plan moves along
    e = moving[len(moving) // 2]  # one mid-path (the first ones pass near the start, checked afresh)
    target = planner.keypoints(((P[e] + P[e + 1]) / 2)[None])[0, -1]  # its tool point half way
    if how == "appears":
        sense(target)
    else:
        for h in np.arange(1.2, -1e-9, -0.004):
            sense(target + [0.0, 0.0, h])
    assert not hit(q0) and seg(P[e], P[e + 1])  # the vase stands on the first plan's path
    res = planner.plan(q0, 0)
    assert res.ok
    C = res.configurations
    assert not any(seg(a, b) for a, b in zip(C[:-1], C[1:]))


def test_unreachable_is_judged_even_when_the_roadmap_is_full(kin):
    """At the vertex cap no biased vertices are added, but a few IK-only executions still tell
    an out-of-reach landmark from a reachable one."""
    model = _tight_model(kin)
    planner = TaskPlanner(model, lambda q: False, lambda a, b: False,
                          settings=TaskPlannerSettings(n_vertices=150, max_vertices=150, seed=0))
    near, far = np.eye(4)[None].copy(), np.eye(4)[None].copy()
    near[0, :3, 3] = [0.7, 0.4, -0.1]
    far[0, :3, 3] = [0.2, 3.0, 0.0]
    q0 = model.mu[0, :7].numpy()
    planner.update_landmarks(["bowl"], near)
    n = planner.roadmap.n
    planner.update_landmarks(["bowl"], far)
    assert planner.plan(q0, 0).status == "unreachable" and planner.roadmap.n == n
    moved = near.copy()
    moved[0, :3, 3] += [0.0, -0.3, 0.0]
    planner.update_landmarks(["bowl"], moved)
    assert planner.plan(q0, 0).ok and planner.roadmap.n == n


def test_guarded_projection_stops_at_the_obstacle_instead_of_entering_it(kin):
    """An 'obstacle' in joint space (left_s0 above a bound) between free starts and their target:
    unguarded, the projection walks into it; guarded, every free start stays free and still
    gets closer to the target, and a start already in collision projects as unguarded."""
    from lfd.planning.biased import project_to_model
    model = _model(kin)
    landmarks = torch.eye(4, dtype=torch.float64)[None]
    g = torch.Generator().manual_seed(4)
    q_target = model.mu[1:2, :7].repeat(6, 1) + 0.05 * torch.randn(6, 7, generator=g, dtype=torch.float64)
    f_target = model.features(q_target, landmarks=landmarks).detach()  # (6, 10)
    bound = float(q_target[:, 0].min()) - 0.3
    calls = []

    def batch_collision_fn(Q):
        calls.append(len(Q))
        return np.asarray(Q)[:, 0] > bound  # (B,) True = in collision
    q0 = q_target.clone()
    q0[:, 0] = bound - 0.4                                 # five free starts ...
    q0[5, 0] = bound + 0.1                                 # ... and one in the obstacle
    q_plain, _ = project_to_model(model, q0, 1, f_target, landmarks, iters=15)
    assert (q_plain[:5, 0] > bound).all()                  # unguarded: into the obstacle
    q_guard, improved = project_to_model(model, q0, 1, f_target, landmarks, iters=15,
                                         batch_collision_fn=batch_collision_fn)
    assert not batch_collision_fn(q_guard[:5].numpy()).any()
    assert bool(improved.all()) and calls
    assert ((q_guard[:5, 0] - bound).abs() < 0.2).all()    # it went as far as the obstacle let it
    torch.testing.assert_close(q_guard[5], q_plain[5])     # a colliding start: no guard


def test_free_posture_chains_hold_the_demonstrated_tool_pose_in_other_arm_postures(kin):
    """With a near-deterministic model, free-posture samples put the tool point where the model
    wants it and turn the gripper as the mean joints do (IK on the whole pose), from arm postures
    spread far from the mean; the default chains stay near the mean posture."""
    from lfd.planning.biased import biased_configurations
    model = _model(kin)
    T = model.mu.shape[0]
    model.sigma_inv = torch.eye(10, dtype=torch.float64).repeat(T, 1, 1) / 1e-4
    landmarks = torch.eye(4, dtype=torch.float64)[None].clone()
    landmarks[0, :3, 3] = torch.tensor([0.7, 0.4, -0.1], dtype=torch.float64)
    mean_pose = kin.fk(model.mu[:, :7])  # (T, 4, 4)
    g = torch.Generator().manual_seed(0)
    Q, valid, steps, reached = biased_configurations(model, landmarks, 40 * T, g, free_posture=True,
                                                     project_iters=0)
    assert steps == T and Q.shape == (40 * T, 7)
    assert reached.mean() > 0.1 and (valid == reached).all()
    Qr = torch.as_tensor(Q[reached])
    t = torch.as_tensor(np.tile(np.arange(T), 40)[reached])
    pose = kin.fk(Qr)
    cos = ((torch.einsum("nij,nij->n", pose[:, :3, :3], mean_pose[t, :3, :3]) - 1) / 2).clamp(-1, 1)
    assert float(torch.arccos(cos).max()) < 0.06                                   # gripper as demonstrated
    tool_world = pose[:, :3, 3] + (pose[:, :3, :3] @ model.tool)
    want = model.mu[t, 7:] @ torch.linalg.inv(model.K_virt_inv(landmarks))[:3, :3].T \
        + torch.linalg.inv(model.K_virt_inv(landmarks))[:3, 3]
    assert float((tool_world - want).norm(dim=1).max()) < 0.006                    # tool point where wanted
    spread = (Qr - model.mu[t, :7]).abs().max(dim=1).values
    assert float(spread.median()) > 0.5                                           # other arm postures
    Qd, _, _, _ = biased_configurations(model, landmarks, 10 * T, torch.Generator().manual_seed(0))
    near = np.abs(Qd - np.tile(model.mu[:, :7].numpy(), (10, 1))).max(1)
    assert np.median(near) < 0.3                                                   # default: near the mean posture


def test_default_roadmap_size_scales_with_the_time_steps(kin):
    from lfd.planning.task_settings import default_vertices
    assert default_vertices(24) == 1000 and default_vertices(48) == 2000 and default_vertices(2) >= 2
    model = _model(kin, T=12)
    assert TaskPlanner(model, lambda q: False, lambda a, b: False).n_vertices == 500
    assert TaskPlanner(model, lambda q: False, lambda a, b: False,
                       settings=TaskPlannerSettings(n_vertices=77)).n_vertices == 77
    with pytest.raises(ValueError, match="n_vertices"):
        TaskPlannerSettings(n_vertices=1)



def test_one_unreachable_step_that_the_task_can_skip_still_plans(kin):
    """One step's tool-point target 3 m away (an accidentally tight, sparsely aligned step): the
    planner plans around it when the learned transitions allow skipping it, and says
    'unreachable' when they do not."""
    for skip, status in ((True, "ok"), (False, "unreachable")):
        model = _tight_model(kin)
        model.mu = model.mu.clone()
        model.mu[2, 7:] = torch.tensor([3.0, 0.0, 0.0], dtype=torch.float64)
        if not skip:
            model.log_trans = model.log_trans.clone()
            model.log_trans[:, 2] = -math.inf
            model.log_trans[:, :2] = torch.log(torch.tensor([0.5, 0.5], dtype=torch.float64))
            model.log_trans[-1] = torch.tensor([0.0, -math.inf, -math.inf])
        planner = TaskPlanner(model, lambda q: False, lambda a, b: False,
                              settings=TaskPlannerSettings(n_vertices=150, seed=0))
        bowl = np.eye(4)[None].copy()
        bowl[0, :3, 3] = [0.7, 0.4, -0.1]
        planner.update_landmarks(["bowl"], bowl)
        res = planner.plan(model.mu[0, :7].numpy(), 0)
        assert res.status == status, res.message
        if res.ok:
            assert 2 not in set(res.time_steps.tolist())


def test_projection_with_a_step_per_row_equals_one_step_at_a_time(kin):
    """``project_to_model`` with each row's own step (the batched chains) gives what each step's
    rows give when projected alone with that step's metric."""
    from lfd.planning.biased import project_to_model
    model = _model(kin)
    T = model.mu.shape[0]
    model.sigma_inv = model.sigma_inv * torch.linspace(0.5, 2.0, T, dtype=torch.float64)[:, None, None]
    landmarks = torch.eye(4, dtype=torch.float64)[None].clone()
    landmarks[0, :3, 3] = torch.tensor([0.7, 0.3, -0.1], dtype=torch.float64)
    g = torch.Generator().manual_seed(7)
    steps = torch.arange(T).repeat(3)  # (3T,)
    q0 = model.mu[steps, :7] + 0.2 * torch.randn(3 * T, 7, generator=g, dtype=torch.float64)
    f = model.mu[steps] + 0.05 * torch.randn(3 * T, 10, generator=g, dtype=torch.float64)
    q, better = project_to_model(model, q0, steps, f, landmarks, iters=8)
    assert bool(better.all()) and float((q - q0).abs().max()) > 0.01
    for t in range(T):
        rows = steps == t
        q_t, better_t = project_to_model(model, q0[rows], t, f[rows], landmarks, iters=8)
        torch.testing.assert_close(q[rows], q_t, rtol=0, atol=1e-12)
        assert torch.equal(better[rows], better_t)


def test_growth_a_round_at_a_time_equals_growth_at_once(kin):
    """After a far landmark move, ``grow(rounds=1)`` adds the first round's vertices and leaves
    ``growth_pending`` set until the last round; the finished roadmap equals the one that
    ``grow()`` makes in one call (the same draws), and the place is then remembered."""
    model = _tight_model(kin)
    near, far = np.eye(4)[None].copy(), np.eye(4)[None].copy()
    near[0, :3, 3] = [0.7, 0.4, -0.1]
    far[0, :3, 3] = [0.6, 0.0, 0.1]
    settings = TaskPlannerSettings(n_vertices=150, seed=0, regrow_vertices=72, min_free_per_step=10**6,
                                   extra_posture_rounds=2)  # every extra round runs
    roadmaps = []
    for chunked in (False, True):
        planner = TaskPlanner(model, lambda q: False, lambda a, b: False, settings=settings)
        planner.update_landmarks(["bowl"], near)
        n0 = planner.roadmap.n
        planner.update_landmarks(["bowl"], far, grow=False)
        assert planner.growth_pending and planner.roadmap.n == n0
        if chunked:
            sizes = []
            while planner.growth_pending:
                assert planner.grow(rounds=1)
                sizes.append(planner.roadmap.n)
            assert len(sizes) == 4 and sizes == sorted(set(sizes))  # 2 rounds + 2 extra, each adds
        else:
            assert planner.grow() and not planner.growth_pending
        assert not planner.grow(rounds=1) and not planner.growth_pending  # grown for this place
        roadmaps.append(planner.roadmap)
        assert planner.plan(model.mu[0, :7].numpy(), 0).ok
    assert roadmaps[0].n == roadmaps[1].n > n0
    np.testing.assert_array_equal(roadmaps[0].vertices, roadmaps[1].vertices)
    with pytest.raises(ValueError, match="rounds"):
        planner.grow(rounds=0)


class _RowCounting(_CountingSums):
    """Counts the rows each evaluation is given: configurations, and runs when it sums."""

    def __init__(self, cost, sums: bool):
        super().__init__(cost)
        self.rows = 0
        self.sums = sums

    def evaluate(self, parts, landmarks):
        self.rows += len(parts[0])
        return super().evaluate(parts, landmarks)

    def prepare_sums(self, Q, counts):
        return super().prepare_sums(Q, counts) if self.sums else None

    def evaluate_sums(self, parts, landmarks):
        self.rows += len(parts[0])
        return super().evaluate_sums(parts, landmarks)


@pytest.mark.parametrize("sums", [True, False])
def test_a_grown_roadmap_costs_its_new_edges_alone_and_equals_a_full_costing(kin, sums):
    """After the roadmap grows (new vertices with their nearest-neighbour and chain edges, then
    edges alone between old vertices), the edge store evaluates only the new vertices and the
    new edges (their summed runs, or their interior nodes one by one), and the costs equal a
    fresh store's over the whole grown roadmap; new landmarks cost every edge again."""
    model = _random_cov_model(kin, "attitude", True)
    names = ["cup", "bowl"]
    poses = np.stack([_pose([0.0, 0.0, 0.8], [0.6, -0.2, 0.0]), _pose([0.3, -0.2, 0.1], [0.7, 0.4, -0.1])])
    planner = TaskPlanner(model, lambda q: False, lambda a, b: False,
                          settings=TaskPlannerSettings(n_vertices=60, seed=0))
    planner.update_landmarks(names, poses)
    landmarks = model.select_landmarks(names, poses)
    rm, E0 = planner.roadmap, planner.planner.edges
    counted = _RowCounting(E0.step_cost, sums)
    store = EdgeStore(rm, counted, E0.stay, E0.dt, E0.vmax, E0.quad_dt)
    store.invalidate(landmarks=landmarks)
    ell0, W0 = store.costs()
    for grow in ("vertices", "edges"):
        n0, e0 = rm.n, len(store.ends)
        if grow == "vertices":
            ids = rm.add_vertices(kin.sample_uniform(25, generator=torch.Generator().manual_seed(8)).numpy())
            rm.add_edges(np.stack([ids[:-1], ids[1:]], 1))  # a chain, as a growth round adds
            near = rm.add_vertices(rm.vertices[:5] + 1e-4)  # each joined to its neighbour by one sub-interval
            rm.add_edges(np.stack([np.arange(5), near], 1))
        else:  # edges alone, between vertices the store has costed
            assert rm.add_edges(np.stack([np.arange(40), rm.n - 1 - np.arange(40)], 1)) > 20
        store.sync()
        new_edges = np.arange(e0, len(store.ends))
        assert len(new_edges) > 10 and (store.m[new_edges] > 1).any()
        assert (store.m[new_edges] == 1).any() == (grow == "vertices")  # edges without interior nodes too
        costed, rows = store.counters["costed_edges"], counted.rows
        ell, W = store.costs()
        assert store.counters["costed_edges"] - costed == len(new_edges)  # the new edges alone
        interior = int((store.m[new_edges] - 1).sum())
        assert counted.rows - rows == (rm.n - n0) + (len(new_edges) if sums else interior)
        np.testing.assert_array_equal(ell[:n0], ell0)
        np.testing.assert_array_equal(W[:e0], W0)  # the old edges' costs kept as they were
        fresh = EdgeStore(rm, counted, E0.stay, E0.dt, E0.vmax, E0.quad_dt)
        fresh.invalidate(landmarks=landmarks)
        ell_f, W_f = fresh.costs()
        np.testing.assert_allclose(ell, ell_f, rtol=1e-12, atol=1e-12 * np.abs(ell_f).max())
        finite = np.isfinite(W_f)
        assert np.array_equal(finite, np.isfinite(W)) and finite[e0:].any()
        np.testing.assert_allclose(W[finite], W_f[finite], rtol=1e-10, atol=1e-10 * np.abs(W_f[finite]).max())
        ell0, W0 = ell, W
    moved = poses.copy()
    moved[1] = _pose([0.0, 0.5, -0.2], [0.5, 0.1, 0.2])
    store.invalidate(landmarks=model.select_landmarks(names, moved))
    costed = store.counters["costed_edges"]
    assert np.abs(store.costs()[1][finite] - W[finite]).max() > 1.0
    assert store.counters["costed_edges"] - costed == len(W)  # every edge again


def test_the_plan_plot_is_a_png_and_leaves_the_callers_matplotlib_alone(kin, tmp_path):
    """``lfd.plots.plot_plan_features`` writes a picture of the plan against the learned means
    without pyplot: the caller's backend and open figures are untouched."""
    import matplotlib
    from PIL import Image

    from lfd.plots import plot_plan_features
    model = _model(kin)
    backend = matplotlib.get_backend()
    Q = model.mu[:, :7].numpy()
    png = plot_plan_features(model, Q, np.arange(len(Q)), np.eye(4)[None], tmp_path / "plan.png")
    assert matplotlib.get_backend() == backend
    with Image.open(png) as im:
        assert im.format == "PNG" and im.size == (770, 770)


def test_a_start_or_goal_outside_the_joint_limits_gets_its_status(kin):
    """An arm given in degrees was planned from and answered 'ok' (the caller's collision_fn did not
    check limits); beyond the limits by more than a recording's tolerance it is a status naming
    the joints, within it a plan."""
    planner = TaskPlanner(_model(kin), lambda q: False, lambda a, b: False,
                          settings=TaskPlannerSettings(n_vertices=60, seed=0))
    bowl = np.eye(4)
    bowl[:3, 3] = [0.7, 0.4, -0.1]
    planner.update_landmarks(["bowl"], bowl[None])
    q0 = _model(kin).mu[0, :7].numpy()
    res = planner.plan(np.degrees(q0), 0)
    assert res.status == "start_outside_limits" and len(res.configurations) == 0
    assert "left_e1=" in res.message and "outside the joint limits" in res.message
    assert planner.plan(q0, 0, q_goal=np.full(7, 9.0)).status == "goal_outside_limits"
    upper = kin.upper.numpy()
    at_edge = np.minimum(q0, upper)
    at_edge[3] = upper[3] + 0.01  # within the recordings' tolerance
    assert planner.plan(at_edge, 0).status not in ("start_outside_limits", "goal_outside_limits")


def test_time_steps_settings_names_and_samples_are_checked(kin):
    """Each was accepted and failed later, or was silently wrong: a float count, a NumPy seed
    (torch's manual_seed refused it), a NaN inflation (a Cholesky error), a dict for the roadmap's
    settings; t_current None, NaN or True; a landmark named twice (the second pose ignored); a
    sample_fn answering (d, n) (reshaped into scrambled configurations) or in degrees (vertices
    no plan should reach)."""
    for kw, fragment in [({"n_vertices": 500.0}, "TaskPlannerSettings.n_vertices must be a whole number >= 2"),
                         ({"extra_posture_rounds": 1.5}, "extra_posture_rounds must be a whole number >= 0"),
                         ({"region_inflation": float("nan")}, "region_inflation must be a finite number > 0"),
                         ({"regrow_distance": float("inf")}, "regrow_distance must be a finite number > 0"),
                         ({"posture_spread": float("nan")}, "posture_spread must be a finite number >= 0"),
                         ({"bias_fraction": float("nan")}, r"bias_fraction must be in \[0, 1\]")]:
        with pytest.raises(ValueError, match=fragment):
            TaskPlannerSettings(**kw)
    with pytest.raises(TypeError, match="TaskPlannerSettings.roadmap must be a RoadmapSettings, got dict"):
        TaskPlannerSettings(roadmap={"k_scale": 2.0})
    settings = TaskPlannerSettings(n_vertices=np.int64(40), seed=np.int64(3))
    assert type(settings.seed) is int and type(settings.n_vertices) is int
    bowl = np.eye(4)
    bowl[:3, 3] = [0.7, 0.4, -0.1]
    planner = TaskPlanner(_model(kin), lambda q: False, lambda a, b: False, settings=settings)
    with pytest.raises(ValueError, match=r"landmark name\(s\) \['bowl'\] given more than once"):
        planner.update_landmarks(["bowl", "bowl"], np.stack([bowl, np.eye(4)]))
    planner.update_landmarks(["bowl"], bowl[None])
    q0 = _model(kin).mu[0, :7].numpy()
    for t in (None, float("nan"), True, "2"):
        with pytest.raises(ValueError, match=rf"Expected t_current an integer in \[0, 5\], got {re.escape(repr(t))}"):
            planner.plan(q0, t)
    assert planner.plan(q0, np.int64(0)).ok
    transposed = TaskPlanner(_model(kin), lambda q: False, lambda a, b: False,
                             sample_fn=lambda n: kin.sample_uniform(n).numpy().T,
                             settings=TaskPlannerSettings(n_vertices=40, seed=0, region_fraction=0.0))
    with pytest.raises(ValueError, match=r"sample_fn\(\d+\) must return \d+ finite configurations, shape \(\d+, 7\); got shape \(7, \d+\)"):
        transposed.update_landmarks(["bowl"], bowl[None])
    degrees = TaskPlanner(_model(kin), lambda q: False, lambda a, b: False,
                          sample_fn=lambda n: np.degrees(kin.sample_uniform(n).numpy()),
                          settings=TaskPlannerSettings(n_vertices=40, seed=0, region_fraction=0.0))
    with pytest.raises(ValueError, match=r"sample_fn\(\d+\) returned \d+ configurations outside the joint limits \(radians\), e\.g\. left_"):
        degrees.update_landmarks(["bowl"], bowl[None])


def test_a_continuous_joint_plans_and_a_joint_without_a_velocity_limit_is_refused(tmp_path):
    """A user's arm with a continuous joint: its default samples were NaN and the build failed in
    scipy; it plans. Without a velocity limit its motions would take no time in the edge costs:
    refused by name."""
    from test_kinematics import arm3

    def model_of(spec):
        kin3 = KinematicModel.from_spec(spec)
        T = 5
        mu = torch.zeros(T, 6, dtype=torch.float64)
        mu[:, 3:] = torch.linspace(0.3, 0.05, T, dtype=torch.float64)[:, None] * torch.tensor([1.0, 0.0, 1.0])
        sigma_inv = torch.diag_embed(1 / torch.tensor([1.0] * 3 + [0.1] * 3, dtype=torch.float64)).repeat(T, 1, 1)
        log_trans = torch.log(torch.tensor([0.5, 0.5], dtype=torch.float64)).repeat(T, 1)
        log_trans[-1] = torch.tensor([0.0, -math.inf])
        return TaskModel(torch.tensor([0.0, 0.0, 0.0], dtype=torch.float64), torch.ones(1, dtype=torch.float64), mu,
                         sigma_inv, log_trans, ["bowl"], spec, task=POWDER, kin=kin3, offsets=(0, 1))

    bowl = np.eye(4)
    bowl[:3, 3] = [0.3, 0.0, 0.2]
    planner = TaskPlanner(model_of(arm3(tmp_path)), lambda q: False, lambda a, b: False,
                          settings=TaskPlannerSettings(n_vertices=80, seed=0))
    planner.update_landmarks(["bowl"], bowl[None])
    res = planner.plan(np.zeros(3), 0)
    assert res.ok, res.message
    assert np.all(np.isfinite(planner.roadmap.vertices))
    with pytest.raises(ValueError, match=r"joint\(s\) \['j2'\] have no velocity limit \(absent, or 0\) in arm3_continuous.urdf"):
        TaskPlanner(model_of(arm3(tmp_path, limit="")), lambda q: False, lambda a, b: False)


def test_a_landmark_that_leaves_gives_back_the_candidates_it_blocked(kin):
    """A sensed 'post' around the middle of the free plan's tool path while the roadmap is built:
    the candidates whose tool point it held are set aside; once it has moved away, the next
    growth (``update_landmarks``, then ``grow``) makes them vertices, where the post stood."""
    model = _model(kin)
    tool = model.tool.detach()
    R = 0.25

    def tip(Q):  # (N, 7) -> (N, 3) tool points
        T = kin.fk(torch.as_tensor(np.array(np.atleast_2d(Q))))
        return (T[:, :3, :3] @ tool + T[:, :3, 3]).numpy()

    far = np.array([0.0, 0.0, 5.0])
    place = {"post": far}

    def cf(q):
        return "post" if np.linalg.norm(tip(q)[0] - place["post"]) < R else ""

    def poses(centre):
        P = np.stack([np.eye(4), np.eye(4)])
        P[1, :3, 3] = centre
        return P

    settings = TaskPlannerSettings(n_vertices=150, seed=0)
    q0 = model.mu[0, :7].numpy()
    free = TaskPlanner(model, cf, lambda a, b: False, settings=settings)
    free.update_landmarks(["bowl", "post"], poses(far))
    path = free.plan(q0, 0).configurations
    place["post"] = centre = tip(path[len(path) // 2])[0]
    p = TaskPlanner(model, cf, lambda a, b: False, settings=settings)
    p.update_landmarks(["bowl", "post"], poses(centre))
    aside, n = p.roadmap.n_set_aside, p.roadmap.n
    assert aside >= 2 and not (np.linalg.norm(tip(p.roadmap.vertices) - centre, axis=1) < R).any()
    place["post"] = far
    p.update_landmarks(["bowl", "post"], poses(far))  # (grow=True: the growth runs now)
    assert p.stats["readmitted_vertices"] == aside and p.roadmap.n_set_aside == 0
    back = tip(p.roadmap.vertices[n:n + aside])
    assert (np.linalg.norm(back - centre, axis=1) < R).all()
    assert p.plan(q0, 0).ok
