"""The planner on a small real scene: a learned-style Baxter model, PyBullet's collision checks.

The plan must be the optimum over the roadmap of the learned cost among collision-free edges:
compared with plain networkx Dijkstra on the fully evaluated product graph, every roadmap edge
segment-checked by the simulator, the costs computed here from ``TaskModel.step_nll`` (not from
the planner's prepared step cost), before and after the bowl moves.
"""

from __future__ import annotations

import math

import networkx as nx
import numpy as np
import pytest
import torch

from lfd.robot.kinematics import KinematicModel
from lfd.learning.model import TaskModel, logdet_tensor
from lfd.robot.robots import BAXTER_LEFT
from lfd.planning.roadmap import k_prm_star
from lfd.planning.task_planner import TaskPlanner, TaskPlannerSettings
from lfd.learning.tasks import POWDER


def sweep_model(home) -> TaskModel:
    """6 steps that sweep the shoulder from 0.7 to -0.5 rad around ``home``; the tool point
    loosely 0.3 m above the bowl."""
    T, d = 6, 7
    mu = torch.zeros(T, d + 3, dtype=torch.float64)
    mu[:, :d] = torch.as_tensor(home, dtype=torch.float64)
    mu[:, 0] = torch.linspace(0.7, -0.5, T, dtype=torch.float64)
    mu[:, d:] = torch.tensor([0.0, 0.0, 0.3], dtype=torch.float64)
    sigma_inv = torch.diag(torch.tensor([4.0] * d + [1.0] * 3, dtype=torch.float64)).repeat(T, 1, 1)
    log_trans = torch.log(torch.tensor([[0.5, 0.4, 0.1]] * T, dtype=torch.float64))
    model = TaskModel(torch.tensor([0.0, 0.0, 0.1], dtype=torch.float64), torch.ones(1, dtype=torch.float64),
                      mu, sigma_inv, log_trans, ["bowl"], BAXTER_LEFT, task=POWDER, covariance="block")
    model.kin = KinematicModel.from_spec(model.robot, dtype=model.dtype)
    return model


@pytest.fixture(scope="module", params=["bool", "named"])
def scene(make_world, request):
    """A powder scene and a planner on a tiny roadmap; ``named``: its collision callable names
    what it hits (``hit_fn``), so the bowl's move resets only what the bowl blocked."""
    from sim import layout as L
    from sim.collision import make_collision_fns
    from sim.scenarios import draw_scenarios
    world = make_world("powder", n_particles=0, scenario=draw_scenarios("powder", 1, 0)[0].placements)
    model = sweep_model(L.HOME_Q)
    # the paper-towel roll under the gripper where the sweep passes (shoulder at 0.4 rad): the
    # cheapest ways through the roadmap cross it, so the lazy checks must drop edges
    q = np.array(L.HOME_Q, dtype=float)
    q[0] = 0.4
    world.set_q(q)
    world.place_object("paper_towels", world.T_world_gripper()[:2, 3])
    world.set_q(L.HOME_Q)
    fns = make_collision_fns(world)
    batch = fns.hit_fn if request.param == "named" else fns.batch_collision_fn
    planner = TaskPlanner(model, fns.collision_fn, fns.segment_fn, batch_collision_fn=batch,
                          settings=TaskPlannerSettings(n_vertices=90, seed=3))
    return world, model, fns, planner, model.mu[0, :7].detach().numpy().copy()


def reference_cost(model, rm, segment_fn, landmarks, q0, t0, dt):
    """Dijkstra on the fully evaluated, eagerly checked product graph ((v | "s"), t)."""
    T, d = model.mu.shape[0], rm.d
    floor = (model.logdet_scale * logdet_tensor(model.sigma_inv)).detach().numpy()  # (T,)

    def ell(Q):  # (N, d) -> (N, T): the Mahalanobis term of Eq. 3
        Q = torch.as_tensor(np.array(Q, dtype=float), dtype=model.dtype)
        return model.step_nll(Q, model.kin.fk(Q), landmarks).detach().numpy() - floor

    tc = model.trans_cost.detach().numpy()  # (T, 3): offsets 0, 1, 2
    vmax = model.kin.velocity.numpy()
    V = np.array(rm.vertices)
    pos = {v: V[v] for v in range(rm.n)}
    pos["s"] = q0
    k = k_prm_star(rm.n + 1, d)
    edges = [(u, w) for u, w in rm.graph.edges if not segment_fn(V[u], V[w])]
    near = np.argsort(np.linalg.norm(V - q0, axis=1), kind="stable")[:k]
    edges += [("s", int(j)) for j in near if not segment_fn(q0, V[j])]
    G = nx.DiGraph()
    for u, w in edges:
        a, b = pos[u], pos[w]
        tau = np.max(np.abs(b - a) / vmax)
        m = max(1, math.ceil(tau / dt - 1e-9))
        vals = ell(a + (b - a) * np.linspace(0, 1, m + 1)[:, None])
        mean = (vals[0] / 2 + vals[1:-1].sum(0) + vals[-1] / 2) / m
        for t in range(T):
            c = tau / dt * (tc[t, 0] + mean[t])
            G.add_edge((u, t), (w, t), weight=c)
            if u != "s":
                G.add_edge((w, t), (u, t), weight=c)
    for v, q in pos.items():
        lq = ell(q[None])[0]
        for t in range(T):
            for j in (1, 2):
                if t + j < T and math.isfinite(tc[t, j]):
                    G.add_edge((v, t), (v, t + j), weight=tc[t, j] + lq[t + j])
        G.add_edge((v, T - 1), "end", weight=0.0)
    return nx.dijkstra_path_length(G, ("s", t0), "end")


def test_plan_is_dijkstras_optimum_among_free_edges_before_and_after_a_move(scene):
    world, model, fns, planner, home = scene
    names, poses = world.sensed_landmarks()
    planner.update_landmarks(names, poses)
    res = planner.plan(home, 0)
    assert res.ok, res.message
    assert res.stats["searches"] >= 2 and res.stats["blocked"] >= 1  # paths through obstacles were dropped
    dt = float(model.task.dt)
    lm = model.select_landmarks(names, poses)
    ref = reference_cost(model, planner.roadmap, fns.segment_fn, lm, home, 0, dt)
    assert res.cost == pytest.approx(ref, rel=1e-7)
    Q = res.configurations
    assert not any(fns.segment_fn(a, b) for a, b in zip(Q[:-1], Q[1:]))
    # the bowl moves onto the path's region: re-plan from a point of the first plan
    world.move_object("bowl", (0.62, 0.15))
    names, poses = world.sensed_landmarks()
    planner.update_landmarks(names, poses, grow=False)
    i = len(Q) // 2
    res2 = planner.plan(Q[i], int(res.time_steps[i]))
    assert res2.ok, res2.message
    lm2 = model.select_landmarks(names, poses)
    ref2 = reference_cost(model, planner.roadmap, fns.segment_fn, lm2, Q[i], int(res.time_steps[i]), dt)
    assert res2.cost == pytest.approx(ref2, rel=1e-7)
    Q2 = res2.configurations
    assert not any(fns.segment_fn(a, b) for a, b in zip(Q2[:-1], Q2[1:]))
