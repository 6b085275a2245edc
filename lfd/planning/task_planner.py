"""A learned task model planned in a new scene: the glue between ``lfd.learning.model`` and ``lfd.planning.planner``.

``TaskPlanner`` takes a ``TaskModel`` and the caller's own callables (``collision_fn``,
``segment_fn``, optionally ``sample_fn``), builds a PRM* whose vertices are biased towards where
the model wants the robot for the current landmarks, and re-plans lazily when landmarks move::

    planner = TaskPlanner(model, collision_fn, segment_fn)
    planner.update_landmarks(names, T_world_landmarks)   # (Z,) names, (Z, 4, 4) poses
    result = planner.plan(q_current, t_current=0)        # lfd.planning.planner.PlanResult

Biased sampling (in the spirit of the paper's [2]): feature vectors are drawn from the learned
per-step Gaussians ``N(mu_t, Sigma_t)`` as chains through the time steps (see
``lfd.planning.biased.biased_configurations``); the task part (the tool point relative to the virtual landmark) is
mapped into the world through the current ``K_virt``, IK places the tool point there, pulled
towards the sampled joints in the null space, and ``project_to_model`` then matches the sample in
the step's learned metric, never stepping from a collision-free configuration into a colliding
one (so a sample whose arm was moved off an obstacle descends towards the demonstration only as
far as the obstacle lets it). A share of the chains starts from other arm postures (and more are
drawn while some time step has too few collision-free vertices). The rest of the roadmap is
joint postures around the task, ``N(mu_t, region_inflation^2 Sigma_t)``, which join the chains,
and uniform samples. When the task-relevant landmarks move by more than ``regrow_distance`` from
every set the roadmap was grown for, new biased samples are added to the same roadmap; it is
never rebuilt. When no sampled execution's IK reaches some step's tool-point target (the
landmark is out of the arm's reach) and the learned transitions cannot skip that step
(``reaches_last_step``), ``plan`` returns the status ``unreachable``.

Interactive rates. A landmark update only marks the edge costs stale (``lfd.planning.edgestore``): the
next plan recomputes all of them in one batch from per-configuration parts prepared once
(``lfd.planning.stepcost.ModelStepCost``). Sensed landmarks are obstacles too: when one moves, the
blocked edges it may have blocked (their witness, the configuration found colliding, within
``object_radius`` of its old place, and not seen hitting something else when the collision
callables name what they hit) and the free edges whose motion passes within it of its new
place are checked again when a path uses them (``lfd.planning.edgestore``). The regrowth after a far move (IK and projection of new biased vertices, seconds)
is kept off the critical path when the caller asks: ``update_landmarks(..., grow=False)`` answers
on the current roadmap, and ``grow()`` adds the vertices afterwards, after which a new plan
improves on the first (an anytime re-plan). ``grow(rounds=1)`` adds them a sampling round at a
time (``growth_pending`` stays set until the last), so that a better plan can follow each round;
``sim.execute`` does this while the robot moves.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from lfd.learning.demo_checks import LIMIT_TOLERANCE
from lfd.learning.model import TaskModel
from lfd.planning.growth import BiasedGrowth
from lfd.planning.planner import ClosedLoopPlanner, PlanResult, time_step
from lfd.planning.roadmap import Roadmap
from lfd.planning.stepcost import FK_BATCH, ModelStepCost
from lfd.planning.task_settings import GROWTH_CAP, TaskPlannerSettings, default_vertices
from lfd.robot.se3 import not_rigid

__all__ = ["MOVE_TOLERANCE", "TaskPlanner", "TaskPlannerSettings"]  # the settings live in lfd.planning.task_settings

MOVE_TOLERANCE = 0.005  # m: a sensed landmark this far from where the planner last accounted for it has moved

def _time_base(model: TaskModel, dt: float | None) -> float:
    """The model's seconds per sample: its task's, or ``dt`` for a model without one."""
    if dt is not None and not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
    if model.task is None:
        if dt is None:  # (was planned at a made-up 0.1 s, which weighs motion against time)
            raise ValueError("the model names no task (its demonstrations had no task.json), so its time step "
                             "is unknown: pass dt= (the demonstrations' sampling interval times the stride "
                             "learned at), or add a task.json to the demonstrations and train again")
        return float(dt)
    if dt is not None and not math.isclose(dt, model.task.dt):
        raise ValueError(f"dt={dt} differs from the model's task {model.task.name!r}, {model.task.dt} s")
    return float(model.task.dt)


class TaskPlanner:
    """Plans a learned task around the caller's obstacles.

    Parameters
    ----------
    model : the learned ``TaskModel`` (its ``kin`` gives FK, limits and velocity limits).
    collision_fn : ``q (d,) -> bool`` (True = in collision).
    segment_fn : ``(q1, q2) -> bool`` (True = the straight joint-space segment collides).
    sample_fn : ``n -> (n, d)`` configurations; uniform within the joint limits by default.
    batch_collision_fn : optional ``(B, d) -> (B,) bool``. The collision callables may name what
        a configuration hits instead (``str``, ``""`` where free; ``lfd.planning.roadmap.Roadmap.hits``):
        with the sensed landmarks' names for the objects (exactly the names ``update_landmarks``
        gets), a landmark that moves away then frees only the edges it blocked, not those blocked
        by the table under it (fewer searches). Every object that moves must then be reported
        (sensed), or an edge it blocked may stay blocked after it left.
    settings : ``TaskPlannerSettings``.
    dt : seconds per sample of the model's time base (Sec. V's edge costs weigh a motion's
        duration in samples), for a model that names no task (learned from demonstrations without
        a task.json: their sampling interval times the stride learned at); a model with a task has
        its task's, and another value is refused.
    """

    def __init__(self, model: TaskModel, collision_fn, segment_fn, sample_fn=None,
                 batch_collision_fn=None, settings: TaskPlannerSettings | None = None, dt: float | None = None):
        self.model = model
        self.dt = _time_base(model, dt)
        self.settings = settings = settings or TaskPlannerSettings()
        self.kin = model.kin
        untimed = [n for n, v in zip(self.kin.joint_names, self.kin.velocity.tolist()) if not math.isfinite(v)]
        if untimed:  # its motions would take no time, so the edge costs would not weigh them
            raise ValueError(f"joint(s) {untimed} have no velocity limit (absent, or 0) in {self.kin.urdf_path.name}: the planner "
                             "times each motion by the joints' velocity limits (the edge costs of Sec. V); give "
                             "them <limit velocity=...>")
        self._gen = torch.Generator().manual_seed(settings.seed)
        self._rng = np.random.default_rng(settings.seed)
        if sample_fn is None:
            def sample_fn(n, _kin=self.kin, _gen=self._gen):
                return _kin.sample_uniform(n, generator=_gen).cpu().numpy()
        self.sample_fn = sample_fn
        T, d = model.time_steps, model.dof
        self.n_vertices = settings.n_vertices or default_vertices(T)
        sigma = torch.linalg.inv(model.sigma_inv.detach())  # (T, F, F) lower Cholesky of Sigma_t
        cov_q = (sigma @ sigma.transpose(-1, -2))[:, :d, :d]  # (T, d, d) joint block
        self._region_mu = model.mu.detach()[:, :d]  # (T, d)
        self._region_L = torch.linalg.cholesky(
            settings.region_inflation ** 2 * cov_q
            + 1e-6 * torch.eye(d, dtype=cov_q.dtype, device=cov_q.device))  # (T, d, d)
        self.collision_fn, self.segment_fn = collision_fn, segment_fn
        self.batch_collision_fn = batch_collision_fn
        self._landmarks: torch.Tensor | None = None  # (Z, 4, 4) kept landmarks, model order
        # every sensed landmark's position (3,) as the planner last accounted for it (first sensed, or
        # last reported as moved): a landmark that drifts a little per update is reported once its
        # drift adds up to MOVE_TOLERANCE
        self._sensed: dict[str, np.ndarray] = {}
        self._vacated: set[str] = set()  # landmarks that moved since the last growth (``Roadmap.readmit``)
        self.growth_pending = False
        self._n_bias = int(round(settings.bias_fraction * self.n_vertices))  # the build's biased vertices
        regrow = settings.regrow_vertices
        self._growth = BiasedGrowth(model, settings, self._gen, settings.max_vertices or GROWTH_CAP * self.n_vertices,
                                    self._n_bias if regrow is None else regrow)
        self.roadmap: Roadmap | None = None
        self.planner: ClosedLoopPlanner | None = None
        self._missing: str | None = None
        self._invalidated_edges = 0

    @property
    def stats(self) -> dict:
        """Counters: roadmap vertices, biased ones among them, regrowths, edges invalidated by
        landmarks that moved, vertices readmitted where a landmark left."""
        rm = self.roadmap
        return {"vertices": rm.n if rm is not None else 0, "invalidated_edges": self._invalidated_edges,
                "readmitted_vertices": rm.counters["readmitted"] if rm is not None else 0, **self._growth.stats}

    # -- sampling -------------------------------------------------------------------------
    def region_samples(self, n: int) -> np.ndarray:
        """``(n, d)`` postures around the task: ``N(mu_t, region_inflation^2 Sigma_t)`` over the
        joint block, ``t`` uniform over the time steps, clamped into the joint limits. They do
        not depend on the landmarks."""
        T, d = self._region_mu.shape
        t = torch.randint(T, (n,), generator=self._gen)
        z = torch.randn(n, d, generator=self._gen, dtype=self.model.dtype).to(self.model.device)
        q = self._region_mu[t] + torch.einsum("nij,nj->ni", self._region_L[t], z)  # (n, d)
        q = torch.maximum(torch.minimum(q, self.kin.upper), self.kin.lower)
        return q.cpu().numpy()

    def _free_space_samples(self, n: int) -> np.ndarray:
        """``(n, d)``: each a region sample with probability ``region_fraction``, else ``sample_fn``."""
        m = int(self._rng.binomial(n, self.settings.region_fraction))
        parts = [self.region_samples(m)]
        if n > m:
            Q = np.asarray(self.sample_fn(n - m), dtype=float)
            if Q.shape != (n - m, self.kin.dof) or not np.all(np.isfinite(Q)):  # (d, n) was reshaped, scrambled
                raise ValueError(f"sample_fn({n - m}) must return {n - m} finite configurations, shape "
                                 f"({n - m}, {self.kin.dof}); got shape {Q.shape}"
                                 + ("" if Q.shape != (n - m, self.kin.dof) else " with NaN or inf"))
            outside = ~self.kin.within_limits(Q, LIMIT_TOLERANCE).cpu().numpy()
            if outside.any():  # (samples in degrees became vertices no plan should reach)
                i = int(np.flatnonzero(outside)[0])
                raise ValueError(f"sample_fn({n - m}) returned {int(outside.sum())} configurations outside the "
                                 f"joint limits (radians), e.g. {self._outside_limits(Q[i])}")
            parts.append(Q)
        return self._rng.permutation(np.concatenate(parts, axis=0))

    # -- landmarks ------------------------------------------------------------------------
    def update_landmarks(self, names, T_world_landmarks, grow: bool = True) -> None:
        """New sensed landmarks ``names (Z_all,)``, ``(Z_all, 4, 4)``; builds the roadmap on first use.

        Every landmark that moved (more than ``MOVE_TOLERANCE`` from where the planner last
        accounted for it, however many updates it took) counts as a moved obstacle, and one first
        sensed after the build as one that appeared: edges near its old and new place are checked
        again. With ``grow=False`` a far move of the task landmarks only sets ``growth_pending``
        (the reachability verdict is the one remembered for the new place, none for a place not
        grown for yet); ``grow()`` adds the biased vertices later."""
        names = [str(n) for n in names]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:  # the first pose was used and the second ignored
            raise ValueError(f"landmark name(s) {twice} given more than once: one pose per landmark")
        poses = np.asarray(T_world_landmarks, dtype=float)
        if poses.shape != (len(names), 4, 4):
            raise ValueError(f"T_world_landmarks must have shape ({len(names)}, 4, 4) for the {len(names)} "
                             f"names, got {poses.shape}")
        bad = np.flatnonzero(not_rigid(poses))  # (a NaN pose is a landmark not sensed: allowed)
        if len(bad):
            raise ValueError(f"the pose of landmark {names[bad[0]]!r} is not a rigid transform (a rotation "
                             f"and a translation, bottom row 0 0 0 1): {poses[bad[0]].tolist()}")
        self._invalidate_moved(names, poses)
        try:
            lm = self.model.select_landmarks(names, poses)
        except ValueError as e:
            self._missing = str(e)
            if self.planner is not None:
                self.planner.update_landmarks(np.full((1,), np.nan))
            return
        if not bool(torch.isfinite(lm).all()):
            self._missing = "a task landmark pose is not finite (not sensed)"
            if self.planner is not None:
                self.planner.update_landmarks(np.full((1,), np.nan))
            return
        self._missing = None
        self._landmarks = lm
        if self.roadmap is None:
            self._build()
        else:
            self.growth_pending = True
            self._growth.recall(lm)
            if grow:
                self.grow()
        assert self.planner is not None  # built above
        self.planner.update_landmarks(lm)

    def _invalidate_moved(self, names: list[str], poses: np.ndarray) -> None:
        """Report to the planner every landmark that moved or appeared since it last accounted for it."""
        for name, T in zip(names, poses):
            pos = T[:3, 3]
            old = self._sensed.get(name)
            if not np.all(np.isfinite(pos)) or (old is not None and np.linalg.norm(pos - old) <= MOVE_TOLERANCE):
                continue  # not sensed now, or still where the planner's edge states saw it
            if self.planner is not None:  # (before the build, the build sees it where it is)
                self._invalidated_edges += self.planner.object_moved(old, pos, self.settings.object_radius, name)
                if old is not None:
                    self._vacated.add(name)
            self._sensed[name] = pos.copy()
        if self.roadmap is not None:
            self.roadmap.set_movable(self._sensed)

    def grow(self, rounds: int | None = None) -> bool:
        """Add biased vertices for the current landmarks if they moved far from every place the
        roadmap was grown for (``regrow_distance``), and update the reachability verdict. First,
        the candidates set aside for hitting a landmark that has moved since are checked again
        and the free ones added (``Roadmap.readmit``; at most half the room ``max_vertices`` leaves).

        ``rounds``: how many sampling rounds to run now (None: all). A regrowth takes a few
        rounds (``lfd.planning.growth``); with ``rounds=1`` each call runs one and ``growth_pending``
        stays True until the last, so a caller can re-plan after each (anytime): the first round
        alone gives the new place most of its vertices. Returns whether vertices were added."""
        if rounds is not None and rounds < 1:
            raise ValueError(f"rounds must be at least 1 or None, got {rounds}")
        self.growth_pending = False
        if self.roadmap is None or self._landmarks is None:
            return False
        before = self.roadmap.n
        room = self._growth.room(self.roadmap) // 2  # (the other half stays for the new place's growth)
        for name in sorted(self._vacated):  # the candidates those landmarks blocked, checked again
            room -= len(self.roadmap.readmit(name, limit=room))
        self._vacated.clear()
        self._growth.grow(self.roadmap, self._landmarks, rounds)
        self.growth_pending = self._growth.pending
        return self.roadmap.n > before

    def keypoints(self, Q) -> np.ndarray:
        """``Q (N, d) -> (N, K, 3)``: the arm's link origins and the tool point, world frame
        (in batches of ``lfd.planning.stepcost.FK_BATCH`` configurations)."""
        Q = torch.as_tensor(np.array(Q, dtype=float), dtype=self.model.dtype, device=self.model.device)
        out = []
        with torch.no_grad():
            Q = Q.reshape(-1, self.kin.dof)
            for Qb in torch.split(Q, FK_BATCH) or (Q,):  # (an empty Q is one empty batch)
                origins, T_world_ee = self.kin.frame_origins(Qb)  # (B, L, 3), (B, 4, 4)
                tool = T_world_ee[:, :3, :3] @ self.model.tool.detach() + T_world_ee[:, :3, 3]
                out.append(torch.cat([origins, tool[:, None]], dim=1).cpu().numpy())
        return np.concatenate(out)

    def _build(self) -> None:
        s = self.settings
        n_bias = self._n_bias
        self.roadmap = Roadmap.build(self._free_space_samples, max(2, self.n_vertices - n_bias), self.collision_fn,
                                     self.segment_fn, batch_collision_fn=self.batch_collision_fn,
                                     settings=s.roadmap, movable=tuple(self._sensed))
        assert self._landmarks is not None  # set by update_landmarks before the build
        self._growth.initial(self.roadmap, self._landmarks, n_bias)
        self.planner = ClosedLoopPlanner(
            self.roadmap, ModelStepCost(self.model), self.model.trans_cost.detach().cpu().numpy(),
            dt=self.dt,
            vmax=self.kin.velocity.cpu().numpy(), offsets=self.model.offsets, settings=s.planner,
            keypoint_fn=self.keypoints)

    # -- planning -------------------------------------------------------------------------
    def plan(self, q_current, t_current: int = 0, q_goal=None) -> PlanResult:
        """Best plan from ``(q_current, t_current)`` to the last time step (see ``ClosedLoopPlanner``)."""
        t_current = time_step(t_current, self.model.time_steps)
        for name, q in (("start", q_current), ("goal", q_goal)):
            outside = self._outside_limits(q)
            if outside:  # (an arm given in degrees was planned from and answered 'ok')
                return self._no_plan(f"{name}_outside_limits", f"the {name} configuration is outside the joint "
                                     f"limits (by more than {LIMIT_TOLERANCE} rad): {outside}")
        if self.planner is None or self._missing:
            return self._no_plan("missing_landmark",
                                 self._missing or "no landmarks yet: call update_landmarks first")
        if not self._growth.can_reach_end(t_current):
            return self._no_plan("unreachable", "the arm cannot reach the tool-point targets of time "
                                 f"step(s) {self._growth.unreachable.tolist()} for these landmarks (IK failed "
                                 "for every sampled execution), and the task cannot skip them")
        return self.planner.plan(q_current, t_current, q_goal)

    def _outside_limits(self, q) -> str:
        """The joints of ``q (d,)`` beyond the URDF limits by more than ``LIMIT_TOLERANCE`` (what
        a recording may show), as ``"name=value"``; ``""`` when none, or when ``q`` is None or not
        ``d`` finite numbers (the planner's ``ValueError`` says so)."""
        if q is None:
            return ""
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != (self.kin.dof,) or not np.all(np.isfinite(q)):
            return ""
        lo, hi = self.kin.lower.cpu().numpy(), self.kin.upper.cpu().numpy()
        out = np.flatnonzero((q < lo - LIMIT_TOLERANCE) | (q > hi + LIMIT_TOLERANCE))
        return ", ".join(f"{self.kin.joint_names[j]}={q[j]:.3f} (limits {lo[j]:.3f}, {hi[j]:.3f})" for j in out)

    def _no_plan(self, status: str, message: str) -> PlanResult:
        d = self.kin.dof
        return PlanResult(status=status, configurations=np.empty((0, d)), time_steps=np.empty(0, int),
                          vertices=np.empty(0, int), cost=math.inf, n_edges_evaluated=0,
                          latency_s=0.0, stats={}, message=message)
