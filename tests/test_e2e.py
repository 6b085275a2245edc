"""End to end: demonstrations -> learning -> planning -> closed-loop execution in PyBullet.

One small pipeline per module (5 powder demonstrations, 2 restarts, a 500-vertex roadmap).
Fast (in ``make test``): the pipeline runs, plans are found, every planned segment passes the
collision checker, a moved bowl triggers a re-plan. Slow (``make test-all``): the runs succeed
by the paper's criterion; an obstacle across the learned path is avoided by the planner but hit
without obstacle avoidance; a moved bowl is re-planned for and the run still succeeds. All three
pass since the reference start, the band and the per-step cost floor (3 passed in 3 min 55 s on
the shared 2 cores; before them, 72%, 50% and 0% of the powder reached the bowl).
"""

from __future__ import annotations

import numpy as np
import pytest

from lfd.robot.kinematics import KinematicModel
from sim import layout as L
from sim.evaluate import VARIANTS
from sim.runner import run_one
from sim.scenarios import Scenario

ROADMAP = 500
FAR = {"paper_towels": (2.5, 2.5), "lamp_shade": (2.5, -2.5, 2.0)}  # out of the scene
LEARNED = {v.name: v for v in VARIANTS}["learned+learned"]
NO_OA = {v.name: v for v in VARIANTS}["no-obstacle-avoidance"]


@pytest.fixture(scope="module")
def model_dir(small_powder_model):
    return small_powder_model


def _scenario(bowl, obstacles=None, bowl_after=None, seed=0) -> Scenario:
    placements = {"bowl": tuple(bowl), **FAR, **(obstacles or {})}
    for i, xy in enumerate(((0.50, 0.0), (1.15, 0.0), (1.15, 0.70), (0.50, 0.55)), start=1):
        placements[f"marker_{i}"] = (*xy, L.TABLE_TOP_Z + L.MARKER_HEIGHT_ABOVE_TABLE)
    return Scenario(task="powder", seed=seed, placements=placements, bowl_after=bowl_after,
                    move_at=0.25 if bowl_after is not None else None)


BOWL = (L.SQUARE_CENTER_XY[0] + 0.10, L.SQUARE_CENTER_XY[1] - 0.10)


@pytest.fixture(scope="module")
def free_run(model_dir):
    return run_one("powder", _scenario(BOWL), LEARNED, str(model_dir), ROADMAP, with_path=True)


def test_pipeline_plans_and_replans(model_dir):
    """Fast: the whole pipeline runs and the closed loop reacts to a moved bowl (one run; the slow
    tests below judge a run without a move by the paper's criterion)."""
    after = (BOWL[0] - 0.25, BOWL[1] + 0.2)
    r = run_one("powder", _scenario(BOWL, bowl_after=after), LEARNED, str(model_dir), ROADMAP, with_path=True)
    assert r["plan_statuses"][0] == "ok", r["reason"]
    assert len(r["task_point_path"]) > 10
    # the tool's attitude is recorded: the spoon was turned over to dump, and tracked as commanded
    assert r["executed_tilt_deg"] > 60, r["executed_tilt_deg"]
    assert abs(r["planned_tilt_deg"] - r["executed_tilt_deg"]) < 5
    assert r["n_replans"] >= 1 and len(r["replan_ms"]) == r["n_replans"]
    assert all(s == "ok" for s in r["plan_statuses"]), r["plan_statuses"]
    # the reaction time is timed too: the landmark update before every re-plan, and the build
    assert len(r["replan_update_ms"]) == r["n_replans"] and all(u > 0 for u in r["replan_update_ms"])
    assert r["build_ms"] > 0
    # the world ran on while the planner worked: each re-plan was charged its wall-clock time
    assert r["latency"] == r["latency_mode"] == "measured" and len(r["charged_ms"]) == r["n_replans"]
    assert all(c >= u + x for c, u, x in zip(r["charged_ms"], r["replan_update_ms"], r["replan_ms"]))
    assert 1 <= r["switches"] <= r["n_replans"]


def test_plans_pass_the_collision_checker(model_dir):
    """Every segment of a plan in an obstacle scene is free by the simulator's own checker."""
    from lfd.learning.model import TaskModel
    from lfd.planning.task_planner import TaskPlanner, TaskPlannerSettings
    from sim.collision import make_collision_fns
    from sim.world import World

    model = TaskModel.load(model_dir)
    model.kin = KinematicModel.from_spec(model.robot)
    roll = (0.5 * (BOWL[0] + L.SOURCE_DEFAULT_XY[0]), 0.5 * (BOWL[1] + L.SOURCE_DEFAULT_XY[1]))
    with World("powder", scenario=_scenario(BOWL, {"paper_towels": roll}).placements, n_particles=0) as w:
        fns = make_collision_fns(w)
        planner = TaskPlanner(model, fns.collision_fn, fns.segment_fn, batch_collision_fn=fns.batch_collision_fn,
                              settings=TaskPlannerSettings(n_vertices=ROADMAP, seed=1))
        planner.update_landmarks(*w.sensed_landmarks())
        res = planner.plan(L.HOME_Q, 0)
        assert res.ok, res.message
        Q = res.configurations
        assert not any(fns.segment_fn(a, b) for a, b in zip(Q[:-1], Q[1:]))
        assert np.all(np.diff(res.time_steps) >= 0) and res.time_steps[-1] == model.time_steps - 1


@pytest.mark.slow
def test_plain_run_succeeds(free_run):
    assert free_run["success"], free_run["reason"]
    assert free_run["fraction_in_bowl"] >= 0.8
    assert free_run["contacts"] == []


@pytest.mark.slow
def test_obstacle_across_the_learned_path(model_dir, free_run):
    path = np.asarray(free_run["task_point_path"])[:, :2]
    bowl, source = np.asarray(BOWL), np.asarray(L.SOURCE_DEFAULT_XY)
    # the first point of the carrying motion that is 0.2-0.3 m from the bowl and clear of the source
    d_bowl = np.linalg.norm(path - bowl, axis=1)
    d_src = np.linalg.norm(path - source, axis=1)
    ok = np.flatnonzero((d_bowl > 0.2) & (d_bowl < 0.3) & (d_src > 0.15))
    assert len(ok), "the learned path never passes 0.2-0.3 m from the bowl"
    roll = tuple(path[ok[0]])
    sc = _scenario(BOWL, {"paper_towels": roll})
    blind = run_one("powder", sc, NO_OA, str(model_dir), ROADMAP)
    assert not blind["success"] and any(c["body"] == "paper_towels" for c in blind["contacts"]), blind["reason"]
    seeing = run_one("powder", sc, LEARNED, str(model_dir), ROADMAP)
    assert seeing["success"], seeing["reason"]


@pytest.mark.slow
def test_a_slow_planner_misses_the_moved_bowl_and_a_fast_one_does_not(model_dir):
    """The world does not wait: the bowl moves shortly before the dump; a planner that takes 2 s
    lets the robot dump where the bowl was, one that takes 0.2 s (or a frozen world) does not."""
    from dataclasses import replace
    after = (BOWL[0] - 0.25, BOWL[1] + 0.2)
    sc = replace(_scenario(BOWL, bowl_after=after), move_at=10 / 24)
    runs = {lat: run_one("powder", sc, LEARNED, str(model_dir), ROADMAP, latency=lat) for lat in ("none", "0.2", "2.0")}
    assert runs["none"]["success"] and runs["0.2"]["success"], (runs["none"]["reason"], runs["0.2"]["reason"])
    assert runs["0.2"]["charged_ms"] and all(c == 200.0 for c in runs["0.2"]["charged_ms"])
    slow = runs["2.0"]
    assert slow["n_replans"] >= 1 and all(c == 2000.0 for c in slow["charged_ms"])
    assert not slow["success"] and slow["fraction_in_bowl"] < 0.5, slow["reason"]


@pytest.mark.slow
def test_moved_bowl_replans_and_succeeds(model_dir):
    after = (BOWL[0] - 0.25, BOWL[1] + 0.2)
    r = run_one("powder", _scenario(BOWL, bowl_after=after), LEARNED, str(model_dir), ROADMAP)
    assert r["n_replans"] >= 1 and len(r["replan_ms"]) == r["n_replans"]
    assert r["success"], r["reason"]
