"""The biased part of a task planner's roadmap: sampled task executions for each landmark place.

``BiasedGrowth`` adds ``biased_configurations`` chains to a ``Roadmap`` for the landmarks' current
place and remembers the places it grew for (the last 64): a place within ``regrow_distance`` of
one of them adds nothing. A growth runs in rounds (``TaskPlannerSettings``): a demonstrated-posture
batch and a moved-posture batch, then extra posture batches while some step has fewer than
``min_free_per_step`` collision-free vertices; a caller can run them one at a time (anytime
re-planning). It also gives the reachability verdict: the task-relevant steps whose tool-point
targets no sampled execution's IK reached, and whether the learned transitions can skip them
(``lfd.learning.model.reaches_last_step``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
import torch

from lfd.learning.model import TaskModel, reaches_last_step
from lfd.planning.biased import biased_configurations, chain_edges
from lfd.planning.roadmap import Roadmap
from lfd.planning.task_settings import TaskPlannerSettings

__all__ = ["TASK_STEP_SD", "BiasedGrowth"]

TASK_STEP_SD = 0.05  # m: a step whose tool-point sd (largest axis) is below this is task-relevant


@dataclass
class _Growth:
    """Biased growth for one landmark place, run a round at a time (see ``BiasedGrowth._new_growth``).

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


class BiasedGrowth:
    """Biased vertices of ``model``'s sampled executions for each landmark place, added to the
    roadmap given to each call; ``generator``: the torch
    generator of every draw (shared with the caller's other samples, so that one seed fixes
    the roadmap); ``max_vertices``: the roadmap never grows past it; ``regrow``: biased samples
    drawn for a new landmark place."""

    def __init__(self, model: TaskModel, settings: TaskPlannerSettings, generator: torch.Generator, max_vertices: int,
                 regrow: int):
        self.model, self.settings, self._gen, self.max_vertices = model, settings, generator, int(max_vertices)
        self.regrow = int(regrow)
        tool = model.tool_features
        task_sd = torch.linalg.eigvalsh(model.covariances.detach()[:, tool, tool]).amax(-1).sqrt()  # (T,) tool point
        self._task_steps = (task_sd <= TASK_STEP_SD).cpu().numpy()  # (T,) bool
        # landmark positions (Z, 3) biased samples were made for, and the time steps whose
        # tool-point targets no sampled execution reached there (the arm cannot: 'unreachable')
        self._grown_for: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=64)  # bounded
        self._unreachable = np.zeros(0, dtype=int)
        self._growth: _Growth | None = None  # a regrowth under way (rounds left)
        self.stats = {"biased_vertices": 0, "regrows": 0}

    @property
    def pending(self) -> bool:
        """Whether a growth has rounds left."""
        return self._growth is not None

    @property
    def unreachable(self) -> np.ndarray:
        """The current verdict: task-relevant steps no sampled execution reached (may be empty)."""
        return self._unreachable

    def can_reach_end(self, t_current: int) -> bool:
        """Whether the task can go from ``t_current`` to its last step around the unreachable steps."""
        return not len(self._unreachable) or reaches_last_step(
            self.model.log_trans.detach().cpu().numpy(), self.model.offsets, self._unreachable, int(t_current))

    def recall(self, landmarks: torch.Tensor) -> None:
        """The verdict for ``landmarks (Z, 4, 4)`` before any growth for their place: the pending
        growth's so far when it is for that place, the remembered one when the roadmap was grown
        near there, else none (not known until grown; the search decides meanwhile). The verdict
        of the place the landmarks left would refuse a place in reach, or pass one out of it."""
        pos = landmarks[:, :3, 3].cpu().numpy()
        g = self._growth
        if g is not None and np.abs(pos - g.pos).max() <= self.settings.regrow_distance:
            self._unreachable = self._verdict(g.reached)
            return
        remembered = self._remembered(pos)
        self._unreachable = np.zeros(0, dtype=int) if remembered is None else remembered

    def _remembered(self, pos: np.ndarray) -> np.ndarray | None:
        """The verdict kept for the place nearest ``pos (Z, 3)`` among those the roadmap was grown
        for, when it is within ``regrow_distance``; else None."""
        dist = [np.abs(pos - p).max() for p, _ in self._grown_for]
        if not dist or min(dist) > self.settings.regrow_distance:
            return None
        return self._grown_for[int(np.argmin(dist))][1]

    def initial(self, rm: Roadmap, landmarks: torch.Tensor, n: int) -> None:
        """Every round of a growth of about ``n`` vertices for ``landmarks (Z, 4, 4)`` (the roadmap's
        build), and its verdict."""
        pos = landmarks[:, :3, 3].cpu().numpy()
        verdict = np.zeros(0, dtype=int)
        if n:
            g = self._new_growth(pos, n)
            self._run_growth(g, rm, landmarks)
            verdict = self._verdict(g.reached)
        self._remember(pos, verdict)

    def grow(self, rm: Roadmap, landmarks: torch.Tensor, rounds: int | None = None) -> None:
        """Run up to ``rounds`` (None: all) rounds of the growth ``landmarks (Z, 4, 4)`` need (none
        when the roadmap was grown near their place), and update the verdict."""
        pos = landmarks[:, :3, 3].cpu().numpy()
        g = self._growth
        if g is None or np.abs(pos - g.pos).max() > self.settings.regrow_distance:
            self._growth = g = self._start_growth(pos, rm, landmarks)  # a growth for another place is dropped
        if g is not None:
            self._run_growth(g, rm, landmarks, rounds)
            self._unreachable = self._verdict(g.reached)
            if g.finished:
                self._remember(g.pos, self._unreachable)
                self._growth = None

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

    def _run_growth(self, g: _Growth, rm: Roadmap, landmarks: torch.Tensor, rounds: int | None = None) -> None:
        """Run up to ``rounds`` (None: all) of ``g``'s rounds; the ones not needed are skipped."""
        k = 0
        while not g.finished and (rounds is None or k < rounds or not self._round_needed(g)):
            if self._round_needed(g):
                self._grow_round(g, rm, landmarks)
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

    def _grow_round(self, g: _Growth, rm: Roadmap, lm: torch.Tensor) -> None:
        """Run ``g``'s next round: sample, add the free vertices and their chain edges."""
        i = g.done
        m, spread, free_posture = g.rounds[i]
        g.done += 1
        Q, valid, steps, reached = biased_configurations(self.model, lm, m, self._gen, posture_spread=spread,
                                                         batch_collision_fn=rm.in_collision,
                                                         free_posture=free_posture)
        g.reached |= reached.reshape(-1, steps).any(0)
        free = valid.copy()
        free[valid] = rm.free_or_set_aside(Q[valid])
        free[np.flatnonzero(free)[max(0, self.room(rm)):]] = False  # never past max_vertices (readmitted
        # vertices may have taken room since the growth's budget was set)
        ids = np.full(len(Q), -1)
        ids[free] = rm.add_vertices(Q[free], check=False)
        rm.add_edges(ids[chain_edges(free, steps)])
        g.per_step += free.reshape(-1, steps).sum(0)
        self.stats["biased_vertices"] += int(free.sum())
        if i >= 2:
            self.stats["extra_posture_rounds"] = self.stats.get("extra_posture_rounds", 0) + 1

    def room(self, rm: Roadmap) -> int:
        """Vertices ``rm`` may still gain before ``max_vertices``."""
        return self.max_vertices - rm.n

    def _start_growth(self, pos: np.ndarray, rm: Roadmap, landmarks: torch.Tensor) -> _Growth | None:
        """The growth the landmarks at ``pos (Z, 3)`` need, or None when the roadmap was grown near
        there already or is full (then the verdict is settled here)."""
        s = self.settings
        room = self.room(rm)
        remembered = self._remembered(pos)
        if remembered is not None:
            self._unreachable = remembered
            return None
        if min(room, self.regrow) <= 0 or not s.bias_fraction:
            # the roadmap is full: a few sampled executions, IK only, still give the verdict
            _, _, steps, reached = biased_configurations(self.model, landmarks, 4 * self.model.mu.shape[0],
                                                         self._gen, project_iters=0)
            self._remember(pos, self._verdict(reached.reshape(-1, steps).any(0)))
            return None
        self.stats["regrows"] += 1
        return self._new_growth(pos, min(room, self.regrow), budget=room)

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
