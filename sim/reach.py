"""Can the arm dump over a bowl at all, with the obstacles where they are? (scenario solvability)

A test scenario is only fair when some motion can do the task. ``start_free`` checks the
simplest part: the arm's start configuration touches nothing. ``DumpReach`` answers the
necessary part of that question without any learned model: is there a collision-free arm
configuration that holds the tool the way the demonstrator holds it when dumping (powder) or
pouring (liquid) over the bowl, facing the bowl from any bearing within ``yaw_span`` of the
demonstrator's? The pose is the demonstrator's nominal one (``sim.demo_paths.dump_pose``); IK
(``lfd.robot.ik``) from ``n_seeds`` seeded starts, collision with the scene checked by
``sim.collision`` including the clearance the planner keeps. Deterministic for given inputs.

Used by ``sim.scenarios`` to redraw scenarios in which an obstacle hangs where every dumping
posture of the arm would be (seen: a low lamp shade between the shoulder and a far bowl).
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["DumpReach"]


class DumpReach:
    """``reach(placements, bowl_xy) -> bool`` for one task, over a private simulator client.

    ``placements``: scenario object name -> ``(x, y)`` or ``(x, y, z)`` (the bowl's entry is
    replaced by ``bowl_xy``). Use as a context manager or call ``close()``.
    """

    def __init__(self, task: str, n_seeds: int = 64, yaw_span_deg: float = 30.0, seed: int = 0):
        from lfd.robot.kinematics import KinematicModel
        from sim.collision import make_collision_fns
        from sim.world import World

        if n_seeds < 1:
            raise ValueError(f"n_seeds must be at least 1, got {n_seeds}")
        self.task = task
        self.world = World(task, n_particles=0)
        self.fns = make_collision_fns(self.world, obstacles=True)
        self.kin = KinematicModel.from_spec(self.world.spec, dtype=torch.float64)
        self.n_seeds, self.yaw_span, self.seed = int(n_seeds), np.deg2rad(yaw_span_deg), int(seed)
        self._home = {name: tuple(self.world.object_pose(name)[:3, 3]) for name in self.world.objects}
        self.calls = 0

    def _set_scene(self, placements: dict, bowl_xy) -> None:
        scene = {**{n: w for n, w in self._home.items() if n not in placements}, **placements,
                 "bowl": tuple(bowl_xy)}
        for name in [n for n in self.world.objects if n not in scene]:
            self.world.remove_object(name)  # an obstacle of an earlier scene
        for name, where in scene.items():
            if name not in self.world.objects:
                self.world.place_object(name, where)
            else:
                self.world.move_object(name, where)

    def start_free(self, placements: dict) -> bool:
        """Whether the arm's start (``layout.HOME_Q``, holding the tool) is collision-free in the
        scene, with the clearance the planner keeps (seen: a vase drawn against the forearm)."""
        from sim import layout as L

        self._set_scene(placements, placements["bowl"])
        return not self.fns.collision_fn(np.asarray(L.HOME_Q, dtype=float))

    def __call__(self, placements: dict, bowl_xy) -> bool:
        from lfd.robot.ik import IKConfig, solve_ik
        from sim.demo_paths import TASK_POINTS, dump_pose

        self.calls += 1
        self._set_scene(placements, bowl_xy)
        g = torch.Generator().manual_seed(self.seed)
        yaws = np.linspace(-self.yaw_span, self.yaw_span, self.n_seeds)
        tool_point = np.asarray(TASK_POINTS[self.task])
        T = np.stack([dump_pose(self.task, bowl_xy, dyaw, tool_point) for dyaw in yaws])  # (S, 4, 4)
        q0 = self.kin.sample_uniform(self.n_seeds, generator=g)
        res = solve_ik(self.kin, torch.as_tensor(T), q0, p_ee_tool=torch.as_tensor(tool_point),
                       config=IKConfig(max_iters=120, pos_tol=5e-3, rot_tol=0.05))
        Q = res.q.numpy()[res.success.numpy()]
        return bool(len(Q)) and not bool(self.fns.batch_collision_fn(Q).all())

    def close(self) -> None:
        self.world.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
