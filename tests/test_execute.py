"""The closed loop (``sim.execute``): its clock (planner work is charged in simulated time even
when it gives no plan), and the plan being followed checked when the world changes (the arm stops
before what moved onto its path, holds where a late plan starts). Scripted planners in a real
PyBullet world, so the timing is exact and the contacts are the physics'."""

from __future__ import annotations

import time
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
        self.segment_fn = lambda q1, q2: False  # nothing in its way

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
    """A first plan through ``waypoints`` (home first and last) at evenly spread time steps;
    every later plan records its start, checked in the real world (``collision_fn``), and answers
    'start_in_collision' as the planner does, else ``replan`` ("ok": from there to
    ``then``; "no_path": none), after ``sleep_s`` of wall-clock time."""

    def __init__(self, world, kin, waypoints, fns, replan="ok", then=None, sleep_s=0.0):
        super().__init__(world, kin, "still", time_steps=24)
        self.waypoints, self.collision_fn, self.segment_fn = np.stack(waypoints), fns.collision_fn, fns.segment_fn
        self.replan, self.then, self.sleep_s = replan, then, sleep_s
        self.starts: list[tuple[np.ndarray, bool]] = []

    def plan(self, q, step):
        home = np.asarray(L.HOME_Q, dtype=float)
        if not self.planned:
            self.planned = True
            n = len(self.waypoints)
            steps = np.round(np.linspace(0, 23, n)).astype(int)
            return PlanResult("ok", self.waypoints, steps, np.arange(n), 1.0, 0, 0.001)
        time.sleep(self.sleep_s)
        blocked = bool(self.collision_fn(q))
        self.starts.append((np.array(q), blocked))
        empty = np.zeros((0, 7))
        if blocked or self.replan == "no_path":
            status = "start_in_collision" if blocked else "no_path"
            return PlanResult(status, empty, np.zeros(0, int), np.zeros(0, int), np.inf, 0, 0.001, message="none")
        then = home if self.then is None else self.then
        return PlanResult("ok", np.stack([q, then]), np.array([step, 23]), np.array([-1, 0]), 1.0, 0, 0.001)


class _Commands:
    """The world, with every arm command recorded after the bowl's move."""

    def __init__(self, world):
        self._world, self.after_move = world, None

    def move_object(self, name, xy):
        self.after_move = []
        self._world.move_object(name, xy)

    def command_q(self, q, **kw):
        if self.after_move is not None:
            self.after_move.append(np.array(q))
        self._world.command_q(q, **kw)

    def __getattr__(self, name):
        return getattr(self._world, name)


def _a_and_b(world) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Waypoints A and B, the gripper 30 cm below A at B, and the gripper's place at B ``(3,)``
    (the arm is left at home)."""
    home = np.asarray(L.HOME_Q, dtype=float)
    A, B = home + [0.4, -0.3, 0, 0, 0, 0, 0], home + [0.4, 0, 0.4, 0, 0, 0, 0]
    world.set_q(B)
    gripper_at_B = world.T_world_gripper()[:3, 3]
    world.set_q(home)
    return A, B, gripper_at_B


@pytest.fixture(scope="module")
def blocked_scene(make_world):
    """A powder world, its collision callables, and waypoints A and B (``_a_and_b``) with B where
    a moved bowl's floor makes it collide: ``(world, fns, A, B, bowl_at_B, bowl)``."""
    from sim.collision import make_collision_fns

    world = make_world("powder", n_particles=0)
    A, B, gripper_at_B = _a_and_b(world)
    bowl = tuple(world.sensed_landmarks()[1][0][:2, 3])
    return world, make_collision_fns(world), A, B, tuple(gripper_at_B), bowl


def test_a_bowl_moved_onto_the_segment_being_driven_stops_the_arm_on_it(blocked_scene):
    """The bowl moved onto B as the robot leaves A for B. The re-plan used to start at B (the
    plan's next waypoint) and, finding B in collision, the robot followed its old plan into the
    bowl (a powder scene with another task point, 1300045, failed so). Now the segment ahead is
    checked: the arm stops on it, short of B, the plan starts there, and nothing is touched. The
    stop comes when the check is done: at once with the world frozen, 0.3 s of motion later
    with a fixed latency of 0.3 s (every piece of planner work costs that much)."""
    from sim.scenarios import Scenario

    world, fns, A, B, bowl_at_B, bowl = blocked_scene
    sc = Scenario(task="powder", seed=0, placements={}, bowl_after=bowl_at_B, move_at=0.34)  # step 8 of 24: A->B
    along = {}
    for latency in ("none", 0.3):
        planner = _BlockedAheadPlanner(world, KinematicModel.from_spec(), [L.HOME_Q, A, B, L.HOME_Q], fns)
        result = execute_plan(world, planner, sc, ExecSettings(latency=latency, pace="fastest", settle_s=0.0))
        world.move_object("bowl", bowl)
        (start, blocked), = planner.starts
        assert not blocked and result.plan_statuses == ["ok", "ok"] and result.switches == 1, result.plan_statuses
        share = (start - A) / (B - A + 1e-12)  # the same share of A -> B on the joints that move
        assert np.isclose(share[1], share[2]), share  # on A -> B
        along[latency] = share[1]
        assert result.contacts == [] and result.stopped == "", (result.contacts, result.stopped)
    assert 0 < along["none"] < along[0.3] < 1, along  # short of B, later with the latency


def test_a_re_plan_that_finds_no_path_stops_the_arm_before_the_blocked_segment(blocked_scene):
    """The bowl moved onto B, two waypoints ahead, and the re-plan (from the next waypoint, A2)
    finds no path. The robot used to go on along its old plan, into the bowl; now the rest of the
    old plan is checked, the arm stops at A2, before the segment that collides, and the run ends
    there ('stopped'), without a touch."""
    from sim.scenarios import Scenario

    world, fns, A, B, bowl_at_B, bowl = blocked_scene
    A2 = A + [0, 0.1, 0.1, 0, 0, 0, 0]
    sc = Scenario(task="powder", seed=0, placements={}, bowl_after=bowl_at_B, move_at=0.25)  # step 6: A -> A2
    planner = _BlockedAheadPlanner(world, KinematicModel.from_spec(), [L.HOME_Q, A, A2, B, L.HOME_Q], fns,
                                   replan="no_path")
    result = execute_plan(world, planner, sc, ExecSettings(latency="none", pace="fastest", settle_s=0.0))
    q_end = world.get_q()
    world.move_object("bowl", bowl_at_B)
    assert not fns.segment_fn(A, A2) and fns.segment_fn(A2, B)  # the scene is what the test says
    world.move_object("bowl", bowl)
    assert result.plan_statuses == ["ok", "no_path"] and np.allclose(planner.starts[0][0], A2)
    assert result.contacts == [], result.contacts
    assert "no other plan was found (no_path)" in result.stopped and result.stopped in result.reason, result.reason
    assert np.abs(q_end - A2).max() < 0.02, q_end - A2


def test_with_re_plans_used_up_a_move_onto_the_path_still_stops_the_arm(blocked_scene):
    """``max_replans=0``: no plan is asked for, but the plan being followed is still checked when
    the bowl moves onto B, and the arm stops on A -> B instead of driving into it."""
    from sim.scenarios import Scenario

    world, fns, A, B, bowl_at_B, bowl = blocked_scene
    sc = Scenario(task="powder", seed=0, placements={}, bowl_after=bowl_at_B, move_at=0.34)
    planner = _BlockedAheadPlanner(world, KinematicModel.from_spec(), [L.HOME_Q, A, B, L.HOME_Q], fns)
    result = execute_plan(world, planner, sc, ExecSettings(latency="none", pace="fastest", settle_s=0.0,
                                                           max_replans=0))
    q_end = world.get_q()
    world.move_object("bowl", bowl)
    assert result.n_replans == 0 and planner.starts == [] and len(result.path_check_ms) == 1
    assert result.contacts == [] and "used up" in result.stopped, (result.contacts, result.stopped)
    share = (q_end - A) / (B - A + 1e-12)
    assert 0 < share[1] < 1, share


def test_the_arm_holds_where_a_late_plan_starts_instead_of_driving_on(blocked_scene):
    """A re-plan that arrives later than forecast (its search took 1.5 s of wall clock, charged,
    after the last one took a millisecond): the robot used to drive on along its old plan and
    retrace its way back to where the new plan starts. Now it holds there, at rest, until the
    plan arrives: it never moves along the old plan's B -> home (joint 0 going back)."""
    from sim.scenarios import Scenario

    world, fns, A, B, _, bowl = blocked_scene
    C = B + [0, 0, 0, 0, 0, 0.3, 0]  # the new plan turns the wrist at B
    sc = Scenario(task="powder", seed=0, placements={}, bowl_after=(bowl[0] - 0.1, bowl[1]), move_at=0.34)
    commands = _Commands(world)
    planner = _BlockedAheadPlanner(commands, KinematicModel.from_spec(), [L.HOME_Q, A, B, L.HOME_Q], fns,
                                   then=C, sleep_s=1.5)
    result = execute_plan(commands, planner, sc, ExecSettings(latency="measured", pace="fastest", settle_s=0.0))
    world.move_object("bowl", bowl)
    assert result.plan_statuses == ["ok", "ok"] and result.switches == 1, result.plan_statuses
    assert np.allclose(planner.starts[0][0], B), planner.starts[0][0] - B  # the next waypoint, forecast
    assert commands.after_move, "the bowl never moved"
    j0 = np.array([q[0] for q in commands.after_move])
    assert np.allclose(j0, A[0]), j0.min() - A[0]  # never along B -> home
    assert np.allclose(commands.after_move[-1], C) and result.held_s > 0.2, result.held_s


class _MovesAt(_CountingWorld):
    """The real world, where ``name`` moves to ``where`` at physics step ``at`` (not a scene's
    bowl move: an object of the caller's world that the task model does not use)."""

    def __init__(self, world, name, where, at):
        super().__init__(world)
        self.name, self.where, self.at = name, where, at

    def step(self, n=1):
        super().step(n)
        if self.steps >= self.at and self.name is not None:
            self._world.move_object(self.name, self.where)
            self.name = None


def test_a_distractor_moved_onto_the_path_asks_for_a_plan_and_is_not_hit(make_world):
    """The pour's vase, a sensed landmark the task model does not keep (only the bowl), is moved
    onto B while the robot drives from A to B. Only the task's landmarks used to ask for a plan,
    so the robot drove on into the vase; any sensed landmark's move now does, and the arm stops
    short of it (the check of the plan being followed)."""
    from sim.collision import make_collision_fns

    base = make_world("pour", n_particles=0)
    A, B, gripper_at_B = _a_and_b(base)
    vase = tuple(base.object_pose("vase")[:2, 3])
    fns = make_collision_fns(base)

    def planner():
        return _BlockedAheadPlanner(base, KinematicModel.from_spec(), [L.HOME_Q, A, B, L.HOME_Q], fns)

    s = ExecSettings(latency="none", pace="fastest", settle_s=0.0)
    first = execute_plan(_CountingWorld(base), planner(), settings=s)  # undisturbed: how long the plan takes
    world = _MovesAt(base, "vase", tuple(gripper_at_B[:2]), at=int(0.5 * first.duration_s / L.SIM_DT))  # on A -> B
    result = execute_plan(world, planner(), settings=s)
    assert planner().model.landmark_names == ("bowl",)
    assert fns.segment_fn(A, B) and not fns.collision_fn(A)  # the vase is where the test says
    base.move_object("vase", vase)
    assert result.n_replans >= 1 and result.plan_statuses[1] == "ok", result.plan_statuses
    assert result.contacts == [], result.contacts


class _Events(_CountingWorld):
    """The real world, where objects move at given physics steps: ``events`` ``[(step, name, xy)]``."""

    def __init__(self, world, events):
        super().__init__(world)
        self.events = sorted(events)

    def step(self, n=1):
        for _ in range(int(n)):
            super().step(1)
            while self.events and self.steps >= self.events[0][0]:
                _, name, where = self.events.pop(0)
                self._world.move_object(name, where)


def test_a_second_move_with_re_plans_used_up_keeps_the_stop_before_the_blocked_segment(blocked_scene):
    """``max_replans=0`` and a fixed latency of 0.8 s: the bowl moves onto B and the check stops
    the arm at A2, before the segment that collides. A marker then moves 5 cm (unrelated): its
    check used to put the stop where the robot would be had it moved on (0.8 s later), 71% into
    A2 -> B and into the bowl. Now the stop stays at A2."""
    from sim.scenarios import Scenario

    world, fns, A, B, bowl_at_B, bowl = blocked_scene
    A2 = A + [0, 0.1, 0.1, 0, 0, 0, 0]
    marker = world.object_pose("marker_1")[:3, 3]
    sc = Scenario(task="powder", seed=0, placements={}, bowl_after=bowl_at_B, move_at=0.25)  # step 6: A -> A2
    s = ExecSettings(latency=0.8, pace="fastest", settle_s=0.0, max_replans=0)
    kin = KinematicModel.from_spec()
    first = _CountingWorld(world)
    execute_plan(first, _BlockedAheadPlanner(first, kin, [L.HOME_Q, A, A2, B, L.HOME_Q], fns), sc, s)
    world.move_object("bowl", bowl)
    world.set_q(L.HOME_Q)
    twice = _Events(world, [(first.moves[0][1] + 48, "marker_1", tuple(marker[:2] + [0.05, 0.0]))])
    result = execute_plan(twice, _BlockedAheadPlanner(twice, kin, [L.HOME_Q, A, A2, B, L.HOME_Q], fns), sc, s)
    q_end = world.get_q()
    world.move_object("bowl", bowl)
    world.move_object("marker_1", tuple(marker[:2]))
    assert len(result.path_check_ms) == 2 and result.n_replans == 0  # both moves checked the plan
    assert result.contacts == [] and "used up" in result.stopped, (result.contacts, result.stopped)
    assert np.abs(q_end - A2).max() < 0.03, q_end - A2


def test_a_move_while_an_arrived_plan_waits_for_the_arm_is_seen(blocked_scene):
    """A marker moves as the arm leaves A for B, and its re-plan (from B, the next waypoint)
    arrives at once; the arm drives on to reach its start. The bowl then moves onto B: nothing
    was sensed while the arrived plan waited for the arm, which drove into the bowl. Now the
    planner, free, senses the move, and the arm stops short of the bowl."""
    world, fns, A, B, bowl_at_B, bowl = blocked_scene
    marker = world.object_pose("marker_1")[:3, 3]
    kin = KinematicModel.from_spec()
    s = ExecSettings(latency="none", pace="fastest", settle_s=0.0)
    commands = _Commands(world)
    commands.after_move = []  # every command, from the start
    dry = _CountingWorld(commands)
    execute_plan(dry, _BlockedAheadPlanner(dry, kin, [L.HOME_Q, A, B, L.HOME_Q], fns), settings=s)
    leaves_A = next(k for k, q in enumerate(commands.after_move) if abs(q[2] - A[2]) > 0.04)  # one command a step
    world.set_q(L.HOME_Q)
    events = [(leaves_A, "marker_1", tuple(marker[:2] + [0.05, 0.0])), (leaves_A + 36, "bowl", bowl_at_B)]
    w = _Events(world, events)
    result = execute_plan(w, _BlockedAheadPlanner(w, kin, [L.HOME_Q, A, B, L.HOME_Q], fns), settings=s)
    world.move_object("bowl", bowl)
    world.move_object("marker_1", tuple(marker[:2]))
    assert result.n_replans == 2 and result.contacts == [], (result.replan_steps, result.contacts)
