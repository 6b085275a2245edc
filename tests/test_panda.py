"""Another robot: a Franka Panda (``lfd.robot.robots.PANDA``, its URDF from example-robot-data).
Synthetic Panda demonstrations with a hidden task point are learned (point within 2 cm), and the
learned task is planned for the Panda around an obstacle known only to the user's own
``collision_fn`` (a sphere tested against the arm's link origins in torch): no simulator."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lfd.learning.learn import FitConfig, fit
from lfd.learning.synthetic import make_synthetic
from lfd.planning.task_planner import TaskPlanner, TaskPlannerSettings
from lfd.robot.kinematics import KinematicModel
from lfd.robot.robots import PANDA, robot_from_name


@pytest.fixture(scope="module")
def learned():
    kin = KinematicModel.from_spec(PANDA)
    ds, truth = make_synthetic(kin, n_demos=8, time_steps=8, Z=3, seed=0, robot=PANDA)
    res = fit(ds, kin, FitConfig(time_steps=8, restarts=2, seed=0))
    res.model.kin = kin
    return kin, ds, truth, res


def test_panda_demonstrations_are_learned(learned):
    kin, ds, truth, res = learned
    assert robot_from_name("panda") == PANDA and ds.robot == PANDA and kin.dof == 7
    assert np.linalg.norm(res.model.tool.numpy() - truth.tool) < 0.02
    assert res.kept_landmarks == ("bowl",) and not res.warnings


def test_the_learned_task_is_planned_for_the_panda_with_the_users_collision_check(learned):
    kin, ds, truth, res = learned
    model = res.model
    demo = ds.demos[0]
    q_start = demo.q[0]
    poses = demo.landmarks
    # the user's obstacle: a 2 cm ball on the demonstrated path of the task point, 30% of the way; the
    # user's check: the arm as capsules (2 cm) along its frame origins and on to the tool point
    tool = model.tool.detach()
    T = kin.fk(torch.as_tensor(demo.q))
    path = (T[:, :3, :3] @ tool + T[:, :3, 3]).numpy()
    centre, radius = path[int(0.3 * len(path))], 0.02

    def collision_fn(q) -> bool:
        origins, T_ee = kin.frame_origins(torch.as_tensor(np.asarray(q, dtype=float))[None])
        pts = torch.cat([origins[0], (T_ee[0, :3, :3] @ tool + T_ee[0, :3, 3])[None]]).numpy()  # (K, 3)
        a, b = pts[:-1], pts[1:]
        ab = b - a
        u = np.clip(((centre - a) * ab).sum(1) / np.maximum((ab * ab).sum(1), 1e-12), 0, 1)
        return bool((np.linalg.norm(a + u[:, None] * ab - centre, axis=1) < radius + 0.02).any())

    def segment_fn(q1, q2) -> bool:
        return any(collision_fn(q1 + a * (q2 - q1)) for a in np.linspace(0, 1, 15))

    assert any(map(collision_fn, demo.q)) and not collision_fn(q_start) and not collision_fn(demo.q[-1])
    assert model.task is None  # the user's recordings came without a task.json: the planner is given dt
    planner = TaskPlanner(model, collision_fn, segment_fn, settings=TaskPlannerSettings(n_vertices=400, seed=0),
                          dt=demo.dt)
    planner.update_landmarks(list(ds.landmark_names), poses)
    result = planner.plan(q_start, 0)
    assert result.ok, result.message
    Q = result.configurations
    assert not any(segment_fn(a, b) for a, b in zip(Q[:-1], Q[1:]))
    # the plan ends where the task does: the tool point near the learned mean relative to the bowl
    f = model.features(torch.as_tensor(Q[-1:]), landmarks=model.select_landmarks(ds.landmark_names, poses))
    assert float(torch.linalg.norm(f[0, -3:] - model.mu[-1, -3:])) < 0.05
