"""Closed-loop execution of a task plan on the simulated Baxter (paper Sec. VI).

The arm follows the planned waypoints under PyBullet's position control at the physics rate
(``layout.SIM_DT``, 240 Hz), moving each roadmap edge with a minimum-jerk profile (it starts and
stops at rest, so the powder or liquid is not flung out by velocity jumps at the waypoints) whose
peak joint speeds stay within ``speed`` times the URDF velocity limits and peak accelerations
within ``accel``; at each time-step transition ``t0 -> t1`` it waits, at least one sampling
interval, until it has been in step ``t0`` as long as the demonstrations took on average to get
from ``t0`` to ``t1`` (``lfd.timing.step_clock``: skipped steps keep their time). The path in
configuration space is the plan's; only its timing is chosen here (``lfd.timing``).

The world does not wait for the planner. Every ``sense_period`` seconds the executor senses the
landmarks; when one has moved more than ``replan_threshold`` the planner is asked for a new plan
(a task landmark changes the plan's costs, any landmark its collisions). The plan takes
``latency`` of simulated time to arrive: "measured" charges the wall-clock time of the landmark
update, the path check below and the search, "none" none (the world is frozen while the planner
works: deterministic tests), a number that many seconds. Meanwhile the robot goes on along its
old plan (the bowl may already be elsewhere). The plan starts at the first waypoint at or after
where the robot is expected to be when it arrives (the old plan's configuration and time step
that far ahead: the landmark update's time, already spent, plus the last search's; with a fixed
latency, that figure): a new plan starts at rest, as the arm is at a waypoint, and one that took
over in the middle of an edge stopped the arm dead. The robot does not pass that waypoint: if it
gets there first, it holds at rest until the plan arrives (``held_s``), and the plan takes over
where it starts.

The old plan up to that waypoint is checked against what was just sensed (the planner's
``segment_fn``, the check its own edges had): when a segment ahead now collides (a bowl moved
onto the path), the new plan starts where the free part ends -- the start of that segment or, if
the robot is on it, where the robot is once the check is done (charged like the rest: with the
world frozen an emergency stop on the spot) -- and the robot stops there. A re-plan that finds
no path leaves the robot on its old plan only if the rest of it is free; otherwise the robot
stays where the failed plan was asked from, and when the planner has nothing more to try (no
landmark moved, no growth round pending) the run ends there (``stopped``) rather than drive into
what was seen. With the re-plans used up (``max_replans``) a move still has the old plan checked,
and the robot stops before what blocks it. While a plan is on its way no new one is asked for, and
planner work that gave no plan (a re-plan that found none, a growth round that added no vertex)
keeps the planner busy for its charged time just the same. After a far move the landmark update answers on the current
roadmap and the biased regrowth (``TaskPlanner.grow``) runs a round at a time, each round (a
fraction of a second to a second) followed by a re-plan at the next reading, charged the same way:
the robot executes the first answer while the roadmap grows (anytime). Every re-plan is recorded: ``replan_kind`` ("move" or "growth"), ``replan_update_ms``
(landmark update or growth), ``path_check_ms`` (the old plan's checks), ``replan_ms`` (the search,
``PlanResult.latency_s``, what the paper reports) and ``charged_ms`` (the simulated time it cost);
growth rounds that added no vertex (no re-plan followed) in ``idle_growth_ms``, the simulated time each cost. ``build_ms``
is the first update (the roadmap's construction), before the first plan's ``initial_ms``; the
arm holds at rest while the first plan is made. ``tracking_max_mm``: the largest distance of an
arm frame or the tool point from where it was commanded; ``planned_tilt_deg`` and
``executed_tilt_deg``: the largest tilt of the tool (``sim.attitude``) commanded and reached.

Success is the paper's: nothing the arm or tool touches (table, containers, obstacles) and at least
``success_fraction`` of the particles inside the bowl once they have settled (``sim.judge``).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from lfd.timing import PROFILES, plan_segments, step_clock
from sim import layout as L
from sim.attitude import tilts_of
from sim.follow import PlanFollower
from sim.judge import ContactLog, settle_and_judge
from sim.latency import charged_s, parse_latency

__all__ = ["PACES", "ExecSettings", "RunResult", "execute_plan"]

PACES = ("demonstrated", "fastest")


@dataclass(frozen=True)
class ExecSettings:
    """speed: fraction of the joint velocity limits used on roadmap edges; accel: joint
    acceleration limit (rad/s^2) of the min-jerk profile; profile: "min-jerk" (rest to rest on
    every edge) or "linear" (constant speed, velocity jumps at the waypoints); pace: "demonstrated"
    (time-step transitions at the demonstrations' mean clock) or "fastest" (one sampling interval
    per transition); sense_period: seconds
    between landmark readings; replan_threshold: landmark motion (m) that triggers a re-plan;
    settle_s: time held at the end before particles are counted; success_fraction: particles in the
    bowl needed; force: position-control force (N m); record_every: sim steps between recorded
    task-point samples; frame_every: sim steps between video frames (0: none); latency: how much
    simulated time a plan costs: "measured" (its wall-clock time, landmark update and growth
    included), "none" (the world waits: deterministic) or a fixed number of seconds."""

    speed: float = 0.5
    accel: float = 2.0
    profile: str = "min-jerk"
    pace: str = "demonstrated"
    sense_period: float = 0.1
    replan_threshold: float = 0.01
    settle_s: float = 1.5
    success_fraction: float = 0.8
    force: float = 300.0
    record_every: int = 12
    frame_every: int = 0
    max_replans: int = 50
    latency: str | float = "measured"

    def __post_init__(self):
        object.__setattr__(self, "latency", parse_latency(self.latency))
        if not 0 < self.speed <= 1:
            raise ValueError(f"speed must be in (0, 1], got {self.speed}")
        if self.profile not in PROFILES:
            raise ValueError(f"profile must be one of {PROFILES}, got {self.profile!r}")
        if self.pace not in PACES:
            raise ValueError(f"pace must be one of {PACES}, got {self.pace!r}")
        for name in ("accel", "sense_period", "replan_threshold", "force"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"{name} must be positive and finite, got {getattr(self, name)}")
        if not (math.isfinite(self.settle_s) and self.settle_s >= 0):
            raise ValueError(f"settle_s must be a finite number of seconds >= 0, got {self.settle_s}")
        if not 0 < self.success_fraction <= 1:
            raise ValueError(f"success_fraction must be in (0, 1], got {self.success_fraction}")
        for name, least in (("record_every", 1), ("frame_every", 0), ("max_replans", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise ValueError(f"{name} must be a whole number >= {least}, got {value!r}")


@dataclass
class RunResult:
    """What happened in one execution (plain numbers, JSON-ready through ``to_dict``)."""

    success: bool = False
    reason: str = ""
    fraction_in_bowl: float = 0.0
    fraction_spilled: float = 0.0
    contacts: list = field(default_factory=list)       # [{"body": name, "link": name, "t_s": time}]
    initial_ms: float = math.nan
    replan_ms: list = field(default_factory=list)
    build_ms: float = math.nan  # the first landmark update (the roadmap's construction if new)
    replan_update_ms: list = field(default_factory=list)  # the landmark update before each re-plan
    n_replans: int = 0
    latency_mode: str = "none"  # ExecSettings.latency of the run
    charged_ms: list = field(default_factory=list)  # simulated time each re-plan took
    idle_growth_ms: list = field(default_factory=list)  # simulated time of each growth round that added no vertex
    replan_kind: list = field(default_factory=list)  # each re-plan's cause: "move" or "growth" (anytime)
    replan_steps: list = field(default_factory=list)  # each re-plan's [task step asked at, step it starts from]
    # the plan being followed checked at each re-plan (before it, and after it when it found none),
    # then at each move sensed once the re-plans are used up (they never come back)
    path_check_ms: list = field(default_factory=list)
    switches: int = 0  # re-plans that arrived and took over
    held_s: float = 0.0  # simulated time the arm held at rest waiting for a plan (or for good: ``stopped``)
    stopped: str = ""  # why the arm stopped short of its plan's end ("": it did not)
    tracking_max_mm: float = 0.0  # largest distance of an arm frame or the tool point from where commanded
    planned_tilt_deg: float = 0.0  # largest tilt of the tool (sim.attitude) the arm was commanded to
    executed_tilt_deg: float = 0.0  # largest tilt the tool reached
    plan_statuses: list = field(default_factory=list)
    duration_s: float = 0.0
    task_point_path: list = field(default_factory=list)  # [[x, y, z], ...] world, model tool point
    edges_evaluated: list = field(default_factory=list)

    def to_dict(self, with_path: bool = False) -> dict:
        d = asdict(self)
        if not with_path:
            d.pop("task_point_path")
        return d


def _moved(now: np.ndarray, before: np.ndarray, threshold: float) -> bool:
    """Whether landmark positions ``now (Z, 3)`` differ from ``before`` by more than ``threshold``
    (m) for any landmark, or one was sensed and is not now or the other way round (NaN)."""
    if now.shape != before.shape:
        return True
    lost = np.isnan(now).any(axis=1) != np.isnan(before).any(axis=1)
    with np.errstate(invalid="ignore"):
        return bool(lost.any() or (np.abs(now - before) > threshold).any())


def _tracking_error(planner, q_cmd: np.ndarray, q_act: np.ndarray) -> float:
    """Largest distance (m) between the commanded and the actual place of the arm's frames and
    of the model's tool point (``TaskPlanner.keypoints``)."""
    P = planner.keypoints(np.stack([q_cmd, q_act]))  # (2, K, 3)
    return float(np.linalg.norm(P[0] - P[1], axis=-1).max())


def execute_plan(world, planner, scenario=None, settings: ExecSettings | None = None,
                 q_start=None, frames: list | None = None) -> RunResult:
    """Run the task closed-loop in ``world`` with ``planner`` (an ``lfd.planning.task_planner.TaskPlanner``;
    its ``segment_fn`` also checks the plan being followed when the world changes).

    ``scenario`` (``sim.scenarios.Scenario``) supplies the mid-task bowl move; ``frames``, when a
    list, receives rendered RGB frames every ``settings.frame_every`` steps. The world runs on
    while the planner works (``settings.latency``; see the module docstring).
    """
    return _ClosedLoop(world, planner, scenario, settings or ExecSettings(), q_start, frames).run()


class _ClosedLoop:
    """One closed-loop run (``execute_plan``): the arm's command, the plan it follows, the plan
    on its way, and the ``RunResult`` being filled."""

    def __init__(self, world, planner, scenario, s: ExecSettings, q_start, frames: list | None):
        self.world, self.planner, self.scenario, self.s, self.frames = world, planner, scenario, s, frames
        model = planner.model
        self.vmax = model.kin.velocity.cpu().numpy()
        self.dt = planner.dt
        self.tool = model.tool.detach().cpu().numpy()
        self.clock = (step_clock(model.log_trans.detach().cpu().numpy(), model.offsets, self.dt)
                      if s.pace == "demonstrated" else None)  # (T,)
        self.accel = s.accel if s.profile == "min-jerk" else None
        self.result = RunResult(latency_mode=str(s.latency))
        self.q_cmd = np.asarray(L.HOME_Q if q_start is None else q_start, dtype=float)
        self.qdot = np.zeros_like(self.q_cmd)
        self.step = 0
        self.follow: PlanFollower | None = None
        self.pending: dict | None = None  # a plan on its way: {"arrive": sim step, "res", "pos": where it starts}
        self.stop_at: tuple[int, float] | None = None  # a position of the plan the robot must not pass
        self.release_at: int | None = None  # sim step from which ``stop_at`` no longer holds
        self.idle_held = 0  # growth rounds that added no vertex while the arm was held
        self.busy_until = 0  # sim step until which the planner works on something that gave no plan
        self.search_s: dict = {}  # the last search's time of each kind of re-plan
        self.planned_at: np.ndarray | None = None  # (Z, 3) landmark positions the current plan is for
        self.contacts: ContactLog | None = None

    def run(self) -> RunResult:
        world, s, result = self.world, self.s, self.result
        world.set_q(self.q_cmd)
        world.respawn_particles()
        world.step(int(0.3 / L.SIM_DT))  # let the particles settle in the tool
        self.contacts = ContactLog(world)
        if not self._first_plan():
            return result
        sense_every = max(1, int(round(s.sense_period / L.SIM_DT)))
        move_step = None if self.scenario is None else self.scenario.move_step(self.planner.model.time_steps)
        assert self.follow is not None  # set by _first_plan
        while (not self.follow.done or self.pending is not None) and not result.stopped:
            if self._take_over_arrived_plan():
                break
            if self._holding():  # at the new plan's start before it arrived, or before a blocked segment
                self.qdot = np.zeros_like(self.q_cmd)
                result.held_s += L.SIM_DT
            else:
                self.q_cmd, self.qdot = self.follow.advance()
            self._sim_step()
            self._release_ended_hold()
            if self.step % sense_every:
                continue
            if move_step is not None and self.follow.step_at(self.follow.position) >= move_step:
                world.move_object("bowl", self.scenario.bowl_after)  # the world's event, busy planner or not
                move_step = None
            if self.step >= self.busy_until and (self.pending is None or self.step >= self.pending["arrive"]):
                # the planner is free: it senses (a plan that arrived and waits for the arm to reach its
                # start leaves it free too, then for moves alone: a move in that window was unseen)
                self._sense(moves_only=self.pending is not None)
        settle_and_judge(world, self.contacts, result, s, self.step, self.frames)
        return result

    def _sim_step(self) -> None:
        """One physics step towards the command; contacts, the recorded path and video frames."""
        world, s, result = self.world, self.s, self.result
        world.command_q(self.q_cmd, force=s.force, qdot=self.qdot)
        world.step(1)
        self.step += 1
        assert self.contacts is not None  # made before the first step
        self.contacts.poll(self.step * L.SIM_DT)
        if self.step % s.record_every == 0:
            T = world.T_world_gripper()
            result.task_point_path.append((T[:3, :3] @ self.tool + T[:3, 3]).round(5).tolist())
            q_act = world.get_q()
            err = _tracking_error(self.planner, self.q_cmd, q_act)
            result.tracking_max_mm = max(result.tracking_max_mm, round(err * 1e3, 2))
            planned, executed = tilts_of(self.planner.model.kin, np.stack([self.q_cmd, q_act]))[1]
            result.planned_tilt_deg = max(result.planned_tilt_deg, round(float(planned), 2))
            result.executed_tilt_deg = max(result.executed_tilt_deg, round(float(executed), 2))
        if self.frames is not None and s.frame_every and self.step % s.frame_every == 0:
            self.frames.append(world.render(480, 360))

    def _first_plan(self) -> bool:
        """The roadmap's build and the first plan, the arm holding while it is made; False (the
        reason in the result) when there is none."""
        result = self.result
        names, poses = self.world.sensed_landmarks()
        tic = time.perf_counter()
        self.planner.update_landmarks(names, poses)
        result.build_ms = (time.perf_counter() - tic) * 1e3
        res = self.planner.plan(self.q_cmd, 0)
        result.initial_ms = res.latency_s * 1e3
        result.plan_statuses.append(res.status)
        result.edges_evaluated.append(res.n_edges_evaluated)
        if not res.ok:
            result.reason = f"no initial plan: {res.status} ({res.message})"
            return False
        for _ in range(self._charged_steps(res.latency_s)):
            self._sim_step()  # the arm holds while the first plan is made (the roadmap was built before)
        self.planned_at = np.asarray(poses)[:, :3, 3]
        self.follow = self._timed(res.configurations, res.time_steps)
        self.search_s = {"move": res.latency_s, "growth": res.latency_s}
        return True

    def _timed(self, configurations, time_steps, elapsed: float = 0.0) -> PlanFollower:
        return PlanFollower(plan_segments(configurations, time_steps, self.vmax, self.dt, self.s.speed, self.clock,
                                          self.accel, elapsed=elapsed), self.s.profile, int(time_steps[-1]), elapsed)

    def _release_ended_hold(self) -> None:
        """Lift ``stop_at`` once ``release_at`` has come (a re-plan found no path and the old
        plan is free ahead: the robot goes on along it once the planner's time has passed)."""
        if self.release_at is not None and self.step >= self.release_at:
            self.stop_at = self.release_at = None

    def _holding(self) -> bool:
        """Whether the robot holds still: its plan ended before the new one arrived, or it is
        where it must not go past (``stop_at``)."""
        assert self.follow is not None
        return self.follow.done or (self.stop_at is not None and self.follow.position >= self.stop_at)

    def _take_over_arrived_plan(self) -> bool:
        """Switch to a plan that arrived once the robot is where it starts (it holds there until
        then). Returns True when the new plan is already done (nothing left to execute)."""
        pending, follow = self.pending, self.follow
        assert follow is not None
        if pending is None or self.step < pending["arrive"] or not (follow.done or follow.position >= pending["pos"]):
            return False
        new, pos = pending["res"], pending["pos"]
        self.pending, self.stop_at = None, None
        self.follow = self._timed(new.configurations, new.time_steps, follow.elapsed_at(pos))
        self.result.switches += 1
        return self.follow.done

    def _sense(self, moves_only: bool = False) -> None:
        """Read the landmarks: one that moved asks for a plan (with re-plans used up, only the
        plan being followed is checked); otherwise, while the roadmap still grows for a far move,
        a growth round and a better plan (anytime); with neither, an arm held before a blocked
        segment stops for good (``stopped``). While the arm is held, growth rounds that add no
        vertex count against ``max_replans`` too, so that a growth that never ends cannot hold
        it forever. ``moves_only``: a plan has arrived and waits for the arm to reach its start:
        only a move that can be re-planned for is acted on (its plan replaces the waiting one);
        with the re-plans used up, the move is left to be seen after the switch, against the plan
        then followed."""
        s, result = self.s, self.result
        held = self._holding()
        names, poses = self.world.sensed_landmarks()
        now = np.asarray(poses)[:, :3, 3]
        assert self.planned_at is not None
        moved = _moved(now, self.planned_at, s.replan_threshold)
        can_replan = result.n_replans + self.idle_held < s.max_replans
        if moves_only and not (moved and can_replan):
            return
        if moved:
            self.planned_at = now
        if moved and can_replan:
            self._replan("move", names, poses)
        elif moved:
            self._check_only()
        elif can_replan and getattr(self.planner, "growth_pending", False):
            self._replan("growth")
        elif self.stop_at is not None and held:
            why = (f"no other plan was found ({result.plan_statuses[-1]})" if can_replan
                   else f"the re-plans are used up (max_replans={s.max_replans})")
            result.stopped = f"the plan being followed is blocked ahead and {why}: the arm stopped"

    def _charged_steps(self, wall_s: float) -> int:
        """Simulation steps that planner work of ``wall_s`` wall-clock seconds costs the world."""
        return int(round(charged_s(self.s.latency, wall_s) / L.SIM_DT))

    def _forecast(self, kind: str, spent_s: float) -> float:
        """Seconds from now until a plan being made (``spent_s`` of it done) arrives."""
        if self.s.latency == "none":
            return 0.0
        if self.s.latency == "measured":
            return spent_s + self.search_s[kind]
        return float(self.s.latency)

    def _replan(self, kind: str, names=None, poses=None) -> None:
        """A new plan, made now (wall clock) from where the robot is expected to be when it
        arrives, the charged latency later, and no further than the old plan is still free; the
        robot follows the current plan meanwhile, up to where the new one starts, and holds there."""
        planner, result, follow = self.planner, self.result, self.follow
        assert follow is not None
        tic = time.perf_counter()
        if kind == "move":
            planner.update_landmarks(names, poses, grow=self.s.latency == "none")
        elif not planner.grow(rounds=1):  # the round found no new vertex: no re-plan, but its time passed
            idle_s = time.perf_counter() - tic
            result.idle_growth_ms.append(charged_s(self.s.latency, idle_s) * 1e3)
            self.busy_until = self.step + self._charged_steps(idle_s)
            self.idle_held += int(self._holding())
            return
        update_s = time.perf_counter() - tic
        pos = follow.at_rest_after(follow.predict(self._forecast(kind, update_s)))  # it starts at rest
        if self.stop_at is not None:
            pos = min(pos, self.stop_at)
        pos, blocked = self._stop_before_blocked(pos, tic)
        check_s = time.perf_counter() - tic - update_s
        res = planner.plan(follow.q_at(pos), follow.step_at(pos))
        if not res.ok and not blocked:  # is the old plan still free beyond? (then the robot goes on)
            tac = time.perf_counter()
            blocked = self._first_blocked(pos, None) is not None
            check_s += time.perf_counter() - tac
        wall = time.perf_counter() - tic
        self.search_s[kind] = res.latency_s
        result.n_replans += 1
        result.replan_kind.append(kind)
        result.replan_steps.append([int(follow.step_at(follow.position)), int(follow.step_at(pos))])
        result.replan_update_ms.append(update_s * 1e3)
        result.path_check_ms.append(check_s * 1e3)
        result.replan_ms.append(res.latency_s * 1e3)
        result.plan_statuses.append(res.status)
        result.edges_evaluated.append(res.n_edges_evaluated)
        result.charged_ms.append(charged_s(self.s.latency, wall) * 1e3)
        done_at = self.step + self._charged_steps(wall)
        self.stop_at, self.release_at = pos, None  # the robot holds at the plan's start meanwhile
        if res.ok:
            self.pending = {"arrive": done_at, "res": res, "pos": pos}
        else:  # no plan: the robot stays there if the old plan is blocked ahead, else goes on once told
            self.busy_until = done_at
            self.release_at = None if blocked else done_at
            self._release_ended_hold()  # (no time charged: at once)

    def _stop_before_blocked(self, pos, tic: float) -> tuple[tuple[int, float], bool]:
        """``(pos, blocked)``: ``pos``, or where the robot must stop instead because the plan
        being followed now collides before it: the start of the first blocked segment or, if
        the robot is on it, where the robot is when the check is done (``tic``: when the work
        began, charged; with ``latency="none"``, where it is now: an emergency stop)."""
        follow = self.follow
        assert follow is not None
        blocked = self._first_blocked(follow.position, pos)
        if blocked is None:
            return pos, False
        wall = time.perf_counter() - tic
        told = follow.predict(charged_s(self.s.latency, wall))  # where the news finds it, had it moved on meanwhile
        if self.stop_at is not None and (self.release_at is None
                                         or self.release_at >= self.step + self._charged_steps(wall)):
            told = min(told, self.stop_at)  # it holds there until the news arrives (a second move's check
            # put the stop past a hold before a blocked segment, into the segment)
        return min(max(blocked, told), pos), True

    def _check_only(self) -> None:
        """With re-plans used up, a move still has the plan being followed checked: the robot
        stops before a segment that now collides (``stopped`` once it is held there)."""
        tic = time.perf_counter()
        assert self.follow is not None
        end = (len(self.follow.segs), 0.0)
        pos, blocked = self._stop_before_blocked(end, tic)
        wall = time.perf_counter() - tic
        self.result.path_check_ms.append(wall * 1e3)
        self.busy_until = self.step + self._charged_steps(wall)
        if blocked:
            self.stop_at, self.release_at = pos, None

    def _first_blocked(self, start, end) -> tuple[int, float] | None:
        """The first position of the current plan from ``start`` to ``end`` (None: its end; a
        waypoint, or ``start`` itself) where a segment that now collides begins (``start`` itself
        when the rest of its segment does), or None if all of it is free. Waits (a segment that
        does not move) are not checked again."""
        follow = self.follow
        assert follow is not None
        last = len(follow.segs) if end is None else end[0]
        for i in range(start[0], last):
            q0, q1 = follow.q_at(start) if i == start[0] else follow.segs[i][0], follow.segs[i][1]
            if np.any(q0 != q1) and self.planner.segment_fn(q0, q1):
                return start if i == start[0] else (i, 0.0)
        return None
