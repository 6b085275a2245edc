"""The closed loop's clock (``sim.execute``): planner work is charged in simulated time even
when it gives no plan. A scripted planner in a real PyBullet world, so the timing is exact."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

pytest.importorskip("pybullet")
from lfd.planning.planner import PlanResult  # noqa: E402
from lfd.robot.kinematics import KinematicModel  # noqa: E402
from sim import layout as L  # noqa: E402
from sim.execute import ExecSettings, execute_plan  # noqa: E402

LATENCY_S = 0.5  # a fixed latency: every piece of planner work costs exactly this much simulated time


class _CountingWorld:
    """The real world, with the physics steps counted (the executor's clock, seen from outside)."""

    def __init__(self, world):
        self._world, self.steps, self.moves = world, 0, []

    def step(self, n=1):
        self.steps += n
        self._world.step(n)

    def move_object(self, name, xy):
        self.moves.append((name, self.steps))
        self._world.move_object(name, xy)

    def __getattr__(self, name):
        return getattr(self._world, name)


class _ScriptedPlanner:
    """A first plan along three far waypoints; then, as after a far bowl move, growth is always
    pending but a round adds no vertex ('idle'), or it adds one and the re-plan finds no path
    ('no path'). Records the world's step at each call."""

    def __init__(self, world: _CountingWorld, kin, mode: str, time_steps: int = 4):
        self.world, self.mode, self.kin = world, mode, kin
        self.model = SimpleNamespace(kin=kin, tool=torch.zeros(3, dtype=torch.float64), landmark_names=("bowl",),
                                     time_steps=time_steps)
        self.dt = 0.1
        self.growth_pending = False
        self.calls: list[int] = []
        self.planned = False

    def update_landmarks(self, names, poses, grow=True):
        pass

    def keypoints(self, Q):
        return np.zeros((len(Q), 1, 3))

    def grow(self, rounds=None):
        self.calls.append(self.world.steps)
        return self.mode == "no path"

    def plan(self, q, step):
        home = np.asarray(L.HOME_Q, dtype=float)
        if not self.planned:  # the first plan: its waypoints spread over the model's steps
            self.planned, self.growth_pending = True, self.mode != "still"
            Q = np.stack([home, home + [0.4, 0, 0, 0, 0, 0, 0], home + [0.4, 0, 0.4, 0, 0, 0, 0], home])
            T = self.model.time_steps
            return PlanResult("ok", Q, np.array([0, T // 3, 2 * T // 3, T - 1]), np.arange(4), 1.0, 0, 0.001)
        empty = np.zeros((0, 7))
        return PlanResult("no_path", empty, np.zeros(0, int), np.zeros(0, int), np.inf, 0, 0.001, message="none")


@pytest.mark.parametrize("mode", ["idle", "no path"])
def test_planner_work_without_a_plan_is_charged_in_simulated_time(make_world, mode):
    """Growth rounds that add no vertex, and re-plans that find no path, used to cost no
    simulated time: the planner sensed again 0.1 s later while the robot had not moved on.
    Now the next reading waits until the work's charged latency has passed."""
    world = _CountingWorld(make_world("powder", n_particles=0))
    planner = _ScriptedPlanner(world, KinematicModel.from_spec(), mode)
    s = ExecSettings(latency=LATENCY_S, pace="fastest", settle_s=0.0)
    result = execute_plan(world, planner, settings=s)
    calls = planner.calls
    assert len(calls) >= 3, f"the plan lasted {result.duration_s:.2f} s: too short to see the clock"
    gaps_s = np.diff(calls) * L.SIM_DT
    assert gaps_s.min() >= LATENCY_S - 1e-9, gaps_s  # was the sensing period, 0.1 s
    assert gaps_s.max() <= LATENCY_S + s.sense_period + 1e-9, gaps_s  # sensed again once free
    if mode == "idle":
        assert result.n_replans == 0 and result.idle_growth_ms == [LATENCY_S * 1e3] * len(calls)
    else:
        assert result.n_replans == len(calls) and result.plan_statuses[1:] == ["no_path"] * len(calls)
        assert result.charged_ms == [LATENCY_S * 1e3] * len(calls) and result.idle_growth_ms == []


def test_a_scenes_bowl_move_comes_at_its_share_of_the_models_time_steps(make_world):
    """A scene says when its bowl moves as a share of the task (``Scenario.move_at``): half-way
    is step 12 of a 24-step model and step 24 of a 48-step one, the same moment of the same plan
    (a fixed step, 12, came a waypoint earlier in the 48-step model's)."""
    from sim.scenarios import Scenario

    kin = KinematicModel.from_spec()
    base = make_world("powder", n_particles=0)
    bowl = tuple(base.sensed_landmarks()[1][0][:2, 3])
    s = ExecSettings(latency="none", pace="fastest", settle_s=0.0, max_replans=0)
    moved_at = {}
    for share in (0.2, 0.5):
        sc = Scenario(task="powder", seed=0, placements={}, bowl_after=(bowl[0] - 0.1, bowl[1]), move_at=share)
        for T in (24, 48, 240):
            world = _CountingWorld(base)
            world.move_object("bowl", bowl)  # back in place before the run
            world.moves.clear()
            execute_plan(world, _ScriptedPlanner(world, kin, "still", time_steps=T), sc, s)
            assert [name for name, _ in world.moves] == ["bowl"]
            moved_at[share, T] = world.moves[0][1]
    for share in (0.2, 0.5):  # the plan's waypoints sit at steps 0, T/3, 2T/3, T - 1
        assert moved_at[share, 24] == moved_at[share, 48] == moved_at[share, 240], moved_at
    assert moved_at[0.2, 24] < moved_at[0.5, 24], moved_at


def test_the_bowl_moves_on_time_while_the_planner_is_busy(make_world):
    """The scripted move is the world's: it comes at the same simulated moment whether the
    planner is idle or busy (re-plans that find no path, each 0.5 s of simulated time)."""
    from sim.scenarios import Scenario

    kin = KinematicModel.from_spec()
    base = make_world("powder", n_particles=0)
    bowl = tuple(base.sensed_landmarks()[1][0][:2, 3])
    sc = Scenario(task="powder", seed=0, placements={}, bowl_after=(bowl[0] - 0.1, bowl[1]), move_at=0.5)
    s = ExecSettings(latency=LATENCY_S, pace="fastest", settle_s=0.0)
    moved_at, busy = {}, {}
    for mode in ("still", "no path"):
        world = _CountingWorld(base)
        world.move_object("bowl", bowl)
        world.moves.clear()
        planner = _ScriptedPlanner(world, kin, mode, time_steps=24)
        execute_plan(world, planner, sc, s)
        moved_at[mode], busy[mode] = world.moves[0][1], planner.calls
    busy_steps = int(round(LATENCY_S / L.SIM_DT))
    assert any(c < moved_at["no path"] <= c + busy_steps for c in busy["no path"]), (busy, moved_at)  # mid-work
    assert moved_at["still"] == moved_at["no path"]


class _BlockedAheadPlanner(_ScriptedPlanner):
    """A first plan home -> A -> B -> home; every later plan checks its start in the real world
    (``collision_fn``) and answers 'start_in_collision' as the planner does, or a plan from
    there straight home."""

    def __init__(self, world, kin, A, B, collision_fn):
        super().__init__(world, kin, "still", time_steps=24)
        self.A, self.B, self.collision_fn = A, B, collision_fn
        self.starts: list[tuple[np.ndarray, bool]] = []

    def plan(self, q, step):
        home = np.asarray(L.HOME_Q, dtype=float)
        if not self.planned:
            self.planned = True
            return PlanResult("ok", np.stack([home, self.A, self.B, home]), np.array([0, 8, 16, 23]),
                              np.arange(4), 1.0, 0, 0.001)
        blocked = bool(self.collision_fn(q))
        self.starts.append((np.array(q), blocked))
        if blocked:
            empty = np.zeros((0, 7))
            return PlanResult("start_in_collision", empty, np.zeros(0, int), np.zeros(0, int), np.inf, 0, 0.001,
                              message="start")
        return PlanResult("ok", np.stack([q, home]), np.array([step, 23]), np.array([-1, 0]), 1.0, 0, 0.001)


def test_a_bowl_moved_onto_the_path_ahead_is_not_driven_into(make_world):
    """The bowl moved onto the next waypoint of the plan being followed: the re-plan from there
    answers 'start_in_collision', and the robot used to follow its old plan into the bowl (a
    powder scene with another task point, 1300045, failed so). Now the re-plan starts at the
    latest free waypoint before it, the robot goes back there, and nothing is touched."""
    from sim.collision import make_collision_fns
    from sim.scenarios import Scenario

    world = make_world("powder", n_particles=0)
    kin = KinematicModel.from_spec()
    home = np.asarray(L.HOME_Q, dtype=float)
    A, B = home + [0.4, -0.3, 0, 0, 0, 0, 0], home + [0.4, 0, 0.4, 0, 0, 0, 0]  # B 30 cm below A
    world.set_q(B)
    gripper_at_B = world.T_world_gripper()[:3, 3]
    world.set_q(home)
    bowl = tuple(world.sensed_landmarks()[1][0][:2, 3])
    fns = make_collision_fns(world)
    # the bowl's floor (its base frame) where the gripper will be at B: B collides, A does not;
    # it moves at step 8 of 24 (a share of 0.34), as the robot leaves A for B
    sc = Scenario(task="powder", seed=0, placements={}, bowl_after=tuple(gripper_at_B), move_at=0.34)
    planner = _BlockedAheadPlanner(world, kin, A, B, fns.collision_fn)
    result = execute_plan(world, planner, sc, ExecSettings(latency="none", pace="fastest", settle_s=0.0))
    world.move_object("bowl", bowl)
    blocked = [b for _, b in planner.starts]
    assert blocked[:2] == [True, False], (blocked, result.contacts)  # B first, then the waypoint before it
    assert np.array_equal(planner.starts[0][0], B) and np.array_equal(planner.starts[1][0], A)
    assert result.contacts == [] and result.retraced >= 1, (result.contacts, result.retraced)
    assert result.plan_statuses[1] == "ok"
