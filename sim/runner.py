"""One scenario run: the learned task planned and executed closed-loop in its own PyBullet world.

``run_one`` is what every evaluation job calls (``sim.evaluate``), in a worker process or as a
Ray task (``run_one_shipped``: the model's files arrive as bytes); ``plan_scenario`` is
``lfd-plan``'s single plan. ``scene_planner`` gives both the same planner.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from sim.model_check import MODEL_FILES
from sim.scenarios import Scenario

__all__ = ["EXEC_PACE", "init_worker", "model_files", "plan_scenario", "run_one", "run_one_shipped",
           "scene_planner"]

# how the executor times a plan (``sim.execute.ExecSettings.pace``), logged with every run: runs
# logged without it were paced per visited step (before ``lfd.timing.step_clock``) and are redone
EXEC_PACE = "demonstrated"


def scene_planner(model, fns, task: str, roadmap_size: int | None, seed: int):
    """The ``TaskPlanner`` of an evaluation run (and of ``plan.py``'s single plans) for ``model``
    in a world whose collision callables are ``fns`` (``sim.collision.make_collision_fns``): the
    sweep margin of the task's tool around the model's tool point (``sim.arm_geometry.sweep_margin``),
    and the names of what configurations hit (``fns.hit_fn``), so that a landmark that moves away
    frees only the edges it blocked."""
    from lfd.planning.planner import PlannerSettings
    from lfd.planning.task_planner import TaskPlanner, TaskPlannerSettings
    from sim.arm_geometry import sweep_margin
    margin = sweep_margin(task, model.tool.detach().cpu().numpy())
    settings = TaskPlannerSettings(n_vertices=roadmap_size, seed=seed, planner=PlannerSettings(sweep_margin=margin))
    return TaskPlanner(model, fns.collision_fn, fns.segment_fn, batch_collision_fn=fns.hit_fn, settings=settings)


def init_worker() -> None:
    """First thing in each forked evaluation worker: one torch thread. This process may have run
    torch's thread pool (a model trained in-process by ``ensure_model``, demonstrations made by
    ``sim.demo_job``), and a forked child that starts a parallel region of that pool's OpenMP
    waits forever for threads it does not have."""
    import torch
    torch.set_num_threads(1)


def run_one(task: str, scenario: Scenario, variant, model_dir: str, roadmap_size: int | None,
            video_path: str | None = None, with_path: bool = False, latency: str = "measured") -> dict:
    """One scenario with one variant, in this process. Returns a JSON-ready dict."""
    import torch

    from lfd.learning.model import TaskModel
    from sim.collision import make_collision_fns
    from sim.execute import ExecSettings, execute_plan
    from sim.world import World

    torch.set_num_threads(1)
    tic = time.perf_counter()
    model = TaskModel.load(model_dir)
    with World(task, scenario=scenario.placements) as world:
        fns = make_collision_fns(world, obstacles=variant.obstacles)
        planner = scene_planner(model, fns, task, roadmap_size, scenario.seed)
        frames = [] if video_path else None
        res = execute_plan(world, planner, scenario,
                           ExecSettings(pace=EXEC_PACE, frame_every=48 if video_path else 0, latency=latency),
                           frames=frames)
        if video_path and frames:
            import imageio.v2 as imageio
            imageio.mimsave(video_path, frames[::2], duration=0.2, loop=0)
    out = res.to_dict(with_path=with_path)
    out.update(scenario=scenario.seed, variant=variant.name, wall_s=time.perf_counter() - tic,
               roadmap_size=planner.n_vertices, latency=str(latency), pace=EXEC_PACE,
               roadmap_vertices=planner.roadmap.n if planner.roadmap is not None else 0,
               readmitted_vertices=planner.stats["readmitted_vertices"])
    return out


def run_one_shipped(files: dict, task: str, scenario: Scenario, variant, roadmap_size: int | None,
                    video: bool = False, with_path: bool = False, latency: str = "measured") -> dict:
    """``run_one`` on a worker that has no access to the driver's disk (a Ray task): the model's
    files arrive as ``files`` (``{name: bytes}``, through the object store) and are written to a
    temporary folder; the GIF, when ``video``, comes back as ``row["video_gif"]`` (bytes)."""
    with tempfile.TemporaryDirectory(prefix="lfd-model-") as tmp:
        for name, data in files.items():
            (Path(tmp) / name).write_bytes(data)
        gif = str(Path(tmp) / "run.gif") if video else None
        row = run_one(task, scenario, variant, tmp, roadmap_size, gif, with_path, latency)
        if gif and Path(gif).is_file():
            row["video_gif"] = Path(gif).read_bytes()
    return row


def model_files(model_dir: Path) -> dict:
    """The files ``TaskModel.load`` reads, ``{name: bytes}``: what a remote worker needs."""
    return {name: (model_dir / name).read_bytes() for name in MODEL_FILES}


def plan_scenario(model_dir: Path, scenario: Scenario, roadmap_size: int | None, gui: bool = False,
                  execute: bool = False, progress=None, latency: str = "measured") -> tuple[dict, object, object]:
    """Build the roadmap in the scenario's world, plan once from home (and optionally execute).

    Returns ``(report, plan_result, model)``.
    """
    from lfd.learning.model import TaskModel
    from sim import layout as L
    from sim.collision import make_collision_fns
    from sim.execute import ExecSettings, execute_plan
    from sim.world import World

    model = TaskModel.load(model_dir)
    report = {"scenario": scenario.to_dict(), "latency": str(latency)}
    with World(scenario.task, gui=gui, scenario=scenario.placements) as world:
        fns = make_collision_fns(world, obstacles=True)
        tic = time.perf_counter()
        planner = scene_planner(model, fns, scenario.task, roadmap_size, scenario.seed)
        names, poses = world.sensed_landmarks()
        planner.update_landmarks(names, poses)
        report["roadmap_build_s"] = time.perf_counter() - tic
        res = planner.plan(L.HOME_Q, 0)
        report.update(status=res.status, message=res.message, cost=res.cost,
                      waypoints=len(res.configurations), latency_ms=res.latency_s * 1e3,
                      edges_evaluated=res.n_edges_evaluated, roadmap_vertices=planner.roadmap.n)
        if execute and res.ok:
            run = execute_plan(world, planner, scenario, ExecSettings(latency=latency))
            report["execution"] = run.to_dict()
    return report, res, model
