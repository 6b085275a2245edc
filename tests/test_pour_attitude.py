"""A pour-like synthetic task whose demonstrations roll the wrist through a known attitude: the
model learned with the attitude features, planned in an empty scene, reaches that attitude."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lfd.learning.learn import FitConfig, fit
from lfd.learning.synthetic import make_synthetic
from lfd.planning.task_planner import TaskPlanner, TaskPlannerSettings
from lfd.robot.kinematics import KinematicModel

T_STEPS = 9
ROLL = math.radians(100)


def _y_axes(kin, Q) -> np.ndarray:
    """The gripper's y axis in the world, ``Q (N, d) -> (N, 3)``."""
    with torch.no_grad():
        return kin.fk(torch.as_tensor(np.asarray(Q), dtype=kin.dtype))[:, :3, 1].numpy()


def _angle_deg(a, b) -> float:
    return math.degrees(math.acos(float(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


@pytest.mark.parametrize("feature_set", ["paper", "attitude"])
def test_planned_pour_reaches_the_demonstrated_attitude(feature_set):
    kin = KinematicModel.from_spec()
    ds, truth = make_synthetic(kin, n_demos=8, time_steps=T_STEPS, Z=2, seed=4, roll=ROLL, samples_per_step=(4, 6))
    # the demonstrations' attitude at the end (the pour's peak): the gripper's y axis, world frame
    # (the landmarks do not turn), and the roll they went through to get there
    y_end = np.stack([_y_axes(kin, d.q[-1:])[0] for d in ds.demos])  # (M, 3)
    y_start = np.stack([_y_axes(kin, d.q[:1])[0] for d in ds.demos])
    rolled = [_angle_deg(a, b) for a, b in zip(y_start, y_end)]
    assert min(rolled) > 60, rolled  # a real roll, not a posture the joints' means give for free
    target = y_end.mean(0)
    res = fit(ds, kin, FitConfig(time_steps=T_STEPS, restarts=2, seed=0, features=feature_set))
    model = res.model
    assert model.feature_set == feature_set and model.landmark_names == ("bowl",)
    planner = TaskPlanner(model, lambda q: False, lambda a, b: False,
                          settings=TaskPlannerSettings(n_vertices=400, seed=0))
    bowl = np.eye(4)
    bowl[:3, 3] = [0.75, 0.25, 0.0]  # inside the demonstrations' box, a place none of them had
    planner.update_landmarks(["bowl"], bowl[None])
    plan = planner.plan(ds.demos[0].q[0], 0)
    assert plan.ok, plan.message
    at_peak = plan.configurations[plan.time_steps == T_STEPS - 1]
    errors = [_angle_deg(y, target) for y in _y_axes(kin, at_peak)]
    assert max(errors) < 5.0, errors
