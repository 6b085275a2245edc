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
(``can_bypass``), ``plan`` returns the status ``unreachable``.

Interactive rates. A landmark update only marks the edge costs stale (``lfd.planning.edgestore``): the
next plan recomputes all of them in one batch from per-configuration parts prepared once
(``lfd.planning.stepcost.ModelStepCost``). Sensed landmarks are obstacles too: when one moves, the edges
whose motion passes within ``object_radius`` of its old or new place are checked again when a
path uses them. The regrowth after a far move (IK and projection of new biased vertices, seconds)
is kept off the critical path when the caller asks: ``update_landmarks(..., grow=False)`` answers
on the current roadmap, and ``grow()`` adds the vertices afterwards, after which a new plan
improves on the first (an anytime re-plan). ``grow(rounds=1)`` adds them a sampling round at a
time (``growth_pending`` stays set until the last), so that a better plan can follow each round;
``sim.execute`` does this while the robot moves.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import torch

from lfd.learning.model import TaskModel
from lfd.planning.biased import biased_configurations, chain_edges, project_to_model
from lfd.planning.planner import ClosedLoopPlanner, PlannerSettings, PlanResult
from lfd.planning.roadmap import Roadmap, RoadmapSettings
from lfd.planning.stepcost import ModelStepCost

TASK_STEP_SD = 0.05  # m: a step whose tool-point sd (largest axis) is below this is task-relevant

__all__ = [
    "TaskPlanner",
    "TaskPlannerSettings",
    "biased_configurations",
    "can_bypass",
    "chain_edges",
    "default_vertices",
    "project_to_model",
]

DEFAULT_VERTICES, DEFAULT_VERTICES_STEPS = 1000, 24  # roadmap size for a model of this many steps


def default_vertices(time_steps: int) -> int:
    """Roadmap size for a model of ``time_steps`` steps: 1000 per 24 steps, at least 2."""
    return max(2, round(DEFAULT_VERTICES * time_steps / DEFAULT_VERTICES_STEPS))


@dataclass(frozen=True)
class TaskPlannerSettings:
    """n_vertices: roadmap size; None (default) scales it with the model's time steps,
    ``default_vertices(T)`` = 1000 per 24 steps, so that a model with more steps gets as many
    sampled executions (chains of T biased vertices, ~25) as one with fewer (measured on the
    48-step pour: the three scenes of base seeds 0 and 1 that poured 45-77% into the bowl with
    1000 vertices, 12 executions, poured 85-98% with 2000); bias_fraction: share of vertices from
    the task model's sampled
    executions (IK chains, see ``biased_configurations``); region_fraction: share of the *other*
    vertices drawn around the task's joint postures, ``N(mu_t, region_inflation^2 Sigma_t)`` (joint
    block, random t), the rest uniform within the joint limits (``sample_fn``): the region
    samples join the chains to each other and let paths detour around obstacles the chains run
    into, the uniform ones keep every configuration reachable (asymptotic optimality);
    posture_share, posture_spread: share of the biased vertices whose chains move the sampled
    arm posture by ``N(0, posture_spread^2)`` rad per joint (one offset per chain), reaching the
    same tool points with the arm elsewhere; min_free_per_step, extra_posture_rounds: while some
    time step has fewer than ``min_free_per_step`` collision-free biased vertices (obstacles where
    the demonstrated arm goes), up to ``extra_posture_rounds`` more posture batches are drawn,
    free-posture ones (the demonstrated tool pose held by any arm posture IK finds from a uniform
    start) alternating with moved-posture ones;
    regrow_distance: landmark motion (m) that triggers new biased samples; regrow_vertices: how
    many; max_vertices: the roadmap never grows past this (default 3 x the roadmap size), so a long run
    of landmark moves cannot grow memory without bound; object_radius: a sensed landmark is also an
    obstacle of about this radius (m): when it moves, edges passing near its old or new place are
    checked again; seed: of every random draw. A configuration costs the Mahalanobis term of Eq. 3
    (the step's ``s log|Sigma_t|`` is a constant per step and left out, so costs are >= 0)."""

    n_vertices: int | None = None
    bias_fraction: float = 0.6
    region_fraction: float = 0.67
    region_inflation: float = 2.0
    posture_share: float = 0.33
    posture_spread: float = 1.0
    min_free_per_step: int = 3
    extra_posture_rounds: int = 3
    regrow_distance: float = 0.10
    regrow_vertices: int = 400
    max_vertices: int | None = None
    object_radius: float = 0.13
    seed: int = 0
    roadmap: RoadmapSettings = field(default_factory=RoadmapSettings)
    planner: PlannerSettings = field(default_factory=PlannerSettings)

    def __post_init__(self):
        if self.n_vertices is not None and self.n_vertices < 2:
            raise ValueError(f"n_vertices must be at least 2, got {self.n_vertices}")
        if not 0.0 <= self.bias_fraction <= 1.0:
            raise ValueError(f"bias_fraction must be in [0, 1], got {self.bias_fraction}")
        if not 0.0 <= self.region_fraction <= 1.0 or self.region_inflation <= 0:
            raise ValueError("region_fraction must be in [0, 1] and region_inflation > 0, got "
                             f"{self.region_fraction}, {self.region_inflation}")
        if self.min_free_per_step < 0 or self.extra_posture_rounds < 0:
            raise ValueError("min_free_per_step and extra_posture_rounds must be >= 0, got "
                             f"{self.min_free_per_step}, {self.extra_posture_rounds}")
        if not 0.0 <= self.posture_share <= 1.0 or self.posture_spread < 0:
            raise ValueError("posture_share must be in [0, 1] and posture_spread >= 0, got "
                             f"{self.posture_share}, {self.posture_spread}")
        if not self.object_radius >= 0:
            raise ValueError(f"object_radius must be >= 0, got {self.object_radius}")
        if self.regrow_distance <= 0 or self.regrow_vertices < 0:
            raise ValueError("regrow_distance must be > 0 and regrow_vertices >= 0, got "
                             f"{self.regrow_distance}, {self.regrow_vertices}")


def can_bypass(log_trans: np.ndarray, offsets, blocked, t_start: int) -> bool:
    """Whether the task's time steps lead from ``t_start`` to the last one avoiding ``blocked``.

    ``log_trans (T, K)``: ``log p(t + offsets[k] | t)``, ``-inf`` where not permitted. A step whose
    tool-point target no sampled execution reached does not make the task unreachable when the
    learned transitions can skip it (seen: one sparsely aligned step of the pour, tight by accident,
    at the source container while the bowl was far); a run of such steps, as when the bowl is out of
    the arm's reach, cannot be skipped.
    """
    T = len(log_trans)
    bad = np.zeros(T, dtype=bool)
    bad[np.asarray(blocked, dtype=int)] = True
    ok = np.zeros(T, dtype=bool)  # the robot is at t_start already, reachable or not
    ok[t_start] = True
    for t in range(t_start, T):
        if not ok[t]:
            continue
        for k, lp in zip(offsets, log_trans[t]):
            if k > 0 and t + k < T and np.isfinite(lp) and not bad[t + k]:
                ok[t + k] = True
    return bool(ok[-1])


@dataclass
class _Growth:
    """Biased growth for one landmark place, run a round at a time (see ``TaskPlanner._new_growth``).

    pos: ``(Z, 3)`` the landmark positions it is for; rounds: ``(samples, posture_spread,
    free_posture)`` per round, the first two always run, the others only while some step has
    fewer than ``min_free_per_step`` free vertices and the samples stay within ``budget``;
    per_step: ``(T,)`` collision-free biased vertices per step so far; reached: ``(T,)`` steps
    whose tool-point target some execution's IK reached."""

    pos: np.ndarray
    rounds: list
    budget: int
    per_step: np.ndarray
    reached: np.ndarray
    done: int = 0  # rounds taken (run or skipped)

    @property
    def finished(self) -> bool:
        return self.done >= len(self.rounds)


class TaskPlanner:
    """Plans a learned task around the caller's obstacles.

    Parameters
    ----------
    model : the learned ``TaskModel`` (its ``kin`` gives FK, limits and velocity limits).
    collision_fn : ``q (d,) -> bool`` (True = in collision).
    segment_fn : ``(q1, q2) -> bool`` (True = the straight joint-space segment collides).
    sample_fn : ``n -> (n, d)`` configurations; uniform within the joint limits by default.
    batch_collision_fn : optional ``(B, d) -> (B,) bool``.
    settings : ``TaskPlannerSettings``.
    """

    def __init__(self, model: TaskModel, collision_fn, segment_fn, sample_fn=None,
                 batch_collision_fn=None, settings: TaskPlannerSettings | None = None):
        self.model = model
        self.settings = settings = settings or TaskPlannerSettings()
        self.kin = model.kin
        self._gen = torch.Generator().manual_seed(settings.seed)
        self._rng = np.random.default_rng(settings.seed)
        if sample_fn is None:
            def sample_fn(n, _kin=self.kin, _gen=self._gen):
                return _kin.sample_uniform(n, generator=_gen).cpu().numpy()
        self.sample_fn = sample_fn
        T, F = model.mu.shape
        d = F - 3
        self.n_vertices = settings.n_vertices or default_vertices(T)
        sigma = torch.linalg.inv(model.sigma_inv.detach())  # (T, F, F) lower Cholesky of Sigma_t
        cov_q = (sigma @ sigma.transpose(-1, -2))[:, :d, :d]  # (T, d, d) joint block
        self._region_mu = model.mu.detach()[:, :d]  # (T, d)
        task_sd = torch.linalg.eigvalsh((sigma @ sigma.transpose(-1, -2))[:, d:, d:]).amax(-1).sqrt()  # (T,)
        self._task_steps = (task_sd <= TASK_STEP_SD).cpu().numpy()  # (T,) bool
        self._region_L = torch.linalg.cholesky(
            settings.region_inflation ** 2 * cov_q
            + 1e-6 * torch.eye(d, dtype=cov_q.dtype, device=cov_q.device))  # (T, d, d)
        self.collision_fn, self.segment_fn = collision_fn, segment_fn
        self.batch_collision_fn = batch_collision_fn
        self._landmarks: torch.Tensor | None = None  # (Z, 4, 4) kept landmarks, model order
        self._sensed: dict[str, np.ndarray] = {}  # every sensed landmark's last position (3,)
        self.growth_pending = False
        # landmark positions (Z, 3) biased samples were made for, and the time steps whose
        # tool-point targets no sampled execution reached there (the arm cannot: 'unreachable')
        self._grown_for: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=64)  # bounded
        self._unreachable = np.zeros(0, dtype=int)
        self._growth: _Growth | None = None  # a regrowth under way (rounds left)
        self.roadmap: Roadmap | None = None
        self.planner: ClosedLoopPlanner | None = None
        self._missing: str | None = None
        self.stats = {"vertices_added": 0, "regrows": 0}

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
            parts.append(np.asarray(self.sample_fn(n - m), dtype=float).reshape(n - m, self.kin.dof))
        return self._rng.permutation(np.concatenate(parts, axis=0))

    # -- landmarks ------------------------------------------------------------------------
    def update_landmarks(self, names, T_world_landmarks, grow: bool = True) -> None:
        """New sensed landmarks ``names (Z_all,)``, ``(Z_all, 4, 4)``; builds the roadmap on first use.

        Every landmark that moved (more than 5 mm) counts as a moved obstacle: edges near its old
        and new place are checked again. With ``grow=False`` a far move of the task landmarks
        only sets ``growth_pending``; ``grow()`` adds the biased vertices later."""
        names = [str(n) for n in names]
        poses = np.asarray(T_world_landmarks, dtype=float).reshape(len(names), 4, 4)
        self._invalidate_moved(names, poses)
        try:
            lm = self.model.select_landmarks(names, T_world_landmarks)
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
            if grow:
                self.grow()
        assert self.planner is not None  # built above
        self.planner.update_landmarks(lm)

    def _invalidate_moved(self, names: list[str], poses: np.ndarray) -> None:
        for name, T in zip(names, poses):
            pos = T[:3, 3]
            old = self._sensed.get(name)
            if self.planner is not None and old is not None and np.all(np.isfinite(pos)) \
                    and np.linalg.norm(pos - old) > 0.005:
                r = self.settings.object_radius
                self.stats["invalidated_edges"] = self.stats.get("invalidated_edges", 0) + \
                    self.planner.object_moved(old, pos, r)
            if np.all(np.isfinite(pos)):
                self._sensed[name] = pos.copy()

    def grow(self, rounds: int | None = None) -> bool:
        """Add biased vertices for the current landmarks if they moved far from every place the
        roadmap was grown for (``regrow_distance``), and update the reachability verdict.

        ``rounds``: how many sampling rounds to run now (None: all). A regrowth takes a few
        rounds (``_new_growth``); with ``rounds=1`` each call runs one and ``growth_pending``
        stays True until the last, so a caller can re-plan after each (anytime): the first round
        alone gives the new place most of its vertices. Returns whether vertices were added."""
        if rounds is not None and rounds < 1:
            raise ValueError(f"rounds must be at least 1 or None, got {rounds}")
        self.growth_pending = False
        if self.roadmap is None or self._landmarks is None:
            return False
        before = self.roadmap.n
        pos = self._landmarks[:, :3, 3].cpu().numpy()
        g = self._growth
        if g is None or np.abs(pos - g.pos).max() > self.settings.regrow_distance:
            self._growth = g = self._start_growth(pos)  # a growth for another place is dropped
        if g is not None:
            self._run_growth(g, rounds)
            self._unreachable = self._verdict(g.reached)
            if g.finished:
                self._remember(g.pos, self._unreachable)
                self._growth = None
        self.growth_pending = self._growth is not None
        return self.roadmap.n > before

    def keypoints(self, Q) -> np.ndarray:
        """``Q (N, d) -> (N, K, 3)``: the arm's link origins and the tool point, world frame."""
        Q = torch.as_tensor(np.array(Q, dtype=float), dtype=self.model.dtype, device=self.model.device)
        with torch.no_grad():
            origins, T_world_ee = self.kin.frame_origins(Q)  # (N, L, 3), (N, 4, 4)
            tool = T_world_ee[:, :3, :3] @ self.model.tool.detach() + T_world_ee[:, :3, 3]
        return torch.cat([origins, tool[:, None]], dim=1).cpu().numpy()

    def _new_growth(self, pos: np.ndarray, n: int, budget: int | None = None) -> _Growth:
        """A growth of about ``n`` biased vertices (collision-free ones) with their chain edges,
        for landmarks at ``pos (Z, 3)``: a share ``posture_share`` of them from chains whose arm
        posture is moved by ``posture_spread`` (an obstacle may sit where the demonstrated elbow
        was), and extra rounds while some step lacks free vertices, as long as the samples stay
        within ``budget`` (default ``2 n``): free-posture chains (``biased_configurations(
        free_posture=True)``: the demonstrated tool pose held by arm postures from anywhere)
        alternating with moved-posture ones. Every round's projection is guarded by the
        collision check."""
        s = self.settings
        n_moved = int(round(s.posture_share * n))
        T = self.model.mu.shape[0]
        rounds = [(n - n_moved, 0.0, False), (n_moved, s.posture_spread, False)]
        rounds += [(n_moved, s.posture_spread, k % 2 == 0) for k in range(s.extra_posture_rounds)]
        return _Growth(pos=pos, rounds=rounds, budget=2 * n if budget is None else budget,
                       per_step=np.zeros(T, dtype=int), reached=np.zeros(T, dtype=bool))

    def _run_growth(self, g: _Growth, rounds: int | None = None) -> None:
        """Run up to ``rounds`` (None: all) of ``g``'s rounds; the ones not needed are skipped."""
        k = 0
        while not g.finished and (rounds is None or k < rounds or not self._round_needed(g)):
            if self._round_needed(g):
                self._grow_round(g)
                k += 1
            else:
                g.done += 1

    def _round_needed(self, g: _Growth) -> bool:
        """Whether ``g``'s next round runs: the first two always (unless empty), the extra ones
        only while some step has too few free vertices and within the budget."""
        i = g.done
        m = g.rounds[i][0]
        drawn = sum(r[0] for r in g.rounds[:i])
        return m > 0 and (i < 2 or (g.per_step.min() < self.settings.min_free_per_step
                                    and drawn + m <= g.budget))

    def _grow_round(self, g: _Growth) -> None:
        """Run ``g``'s next round: sample, add the free vertices and their chain edges."""
        rm, lm = self.roadmap, self._landmarks
        assert rm is not None and lm is not None  # growth runs on a built roadmap
        i = g.done
        m, spread, free_posture = g.rounds[i]
        g.done += 1
        Q, valid, steps, reached = biased_configurations(self.model, lm, m, self._gen, posture_spread=spread,
                                                         batch_collision_fn=rm.in_collision,
                                                         free_posture=free_posture)
        g.reached |= reached.reshape(-1, steps).any(0)
        free = valid.copy()
        free[valid] = ~rm.in_collision(Q[valid])
        ids = np.full(len(Q), -1)
        ids[free] = rm.add_vertices(Q[free], check=False)
        rm.add_edges(ids[chain_edges(free, steps)])
        g.per_step += free.reshape(-1, steps).sum(0)
        self.stats["vertices_added"] += int(free.sum())
        if i >= 2:
            self.stats["extra_posture_rounds"] = self.stats.get("extra_posture_rounds", 0) + 1

    def _start_growth(self, pos: np.ndarray) -> _Growth | None:
        """The growth the landmarks at ``pos (Z, 3)`` need, or None when the roadmap was grown near
        there already or is full (then the verdict is settled here)."""
        s = self.settings
        assert self.roadmap is not None and self._landmarks is not None  # growth runs on a built roadmap
        room = (s.max_vertices or 3 * self.n_vertices) - self.roadmap.n
        dist = [np.abs(pos - g).max() for g, _ in self._grown_for]
        nearest = int(np.argmin(dist))
        if dist[nearest] <= s.regrow_distance:
            self._unreachable = self._grown_for[nearest][1]
            return None
        if min(room, s.regrow_vertices) <= 0 or not s.bias_fraction:
            # the roadmap is full: a few sampled executions, IK only, still give the verdict
            _, _, steps, reached = biased_configurations(self.model, self._landmarks, 4 * self.model.mu.shape[0],
                                                         self._gen, project_iters=0)
            self._remember(pos, self._verdict(reached.reshape(-1, steps).any(0)))
            return None
        self.stats["regrows"] += 1
        return self._new_growth(pos, min(room, s.regrow_vertices), budget=room)

    def _build(self) -> None:
        s = self.settings
        n_bias = int(round(s.bias_fraction * self.n_vertices))
        self.roadmap = Roadmap.build(self._free_space_samples, max(2, self.n_vertices - n_bias), self.collision_fn,
                                     self.segment_fn, batch_collision_fn=self.batch_collision_fn,
                                     settings=s.roadmap)
        self.stats["vertices_added"] = self.roadmap.n
        assert self._landmarks is not None  # set by update_landmarks before the build
        pos = self._landmarks[:, :3, 3].cpu().numpy()
        verdict = np.zeros(0, dtype=int)
        if n_bias:
            g = self._new_growth(pos, n_bias)
            self._run_growth(g)
            verdict = self._verdict(g.reached)
        self._remember(pos, verdict)
        self.planner = ClosedLoopPlanner(
            self.roadmap, ModelStepCost(self.model), self.model.trans_cost.detach().cpu().numpy(),
            dt=float(self.model.task.dt) if self.model.task else 0.1,
            vmax=self.kin.velocity.cpu().numpy(), offsets=self.model.offsets, settings=s.planner,
            keypoint_fn=self.keypoints)

    def _verdict(self, reached: np.ndarray) -> np.ndarray:
        """Task-relevant time steps whose tool-point targets no sampled execution reached
        (``reached: (T,) bool``). Only steps where the demonstrations held the tool point within
        ``TASK_STEP_SD`` of its mean relative to the landmark count: at the others (the start and
        the end, at the source container) the target relative to a far bowl is loose and may be
        out of reach while the task is not (seen in the soak: a bowl in the square's far corner)."""
        return np.flatnonzero(~reached & self._task_steps)

    def _remember(self, pos: np.ndarray, unreachable: np.ndarray) -> None:
        """The current verdict, kept for the landmark place ``pos (Z, 3)`` (the last 64 places)."""
        self._unreachable = unreachable
        self._grown_for.append((pos, unreachable))

    # -- planning -------------------------------------------------------------------------
    def plan(self, q_current, t_current: int = 0, q_goal=None) -> PlanResult:
        """Best plan from ``(q_current, t_current)`` to the last time step (see ``ClosedLoopPlanner``)."""
        if self.planner is None or self._missing:
            return self._no_plan("missing_landmark",
                                 self._missing or "no landmarks yet: call update_landmarks first")
        if len(self._unreachable) and not can_bypass(self.model.log_trans.detach().cpu().numpy(),
                                                     self.model.offsets, self._unreachable, int(t_current)):
            return self._no_plan("unreachable", "the arm cannot reach the tool-point targets of time "
                                 f"step(s) {self._unreachable.tolist()} for these landmarks (IK failed "
                                 "for every sampled execution), and the task cannot skip them")
        return self.planner.plan(q_current, t_current, q_goal)

    def _no_plan(self, status: str, message: str) -> PlanResult:
        d = self.kin.dof
        return PlanResult(status=status, configurations=np.empty((0, d)), time_steps=np.empty(0, int),
                          vertices=np.empty(0, int), cost=math.inf, n_edges_evaluated=0,
                          latency_s=0.0, stats={}, message=message)
