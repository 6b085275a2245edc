"""Settings of ``lfd.planning.task_planner.TaskPlanner`` (and its roadmap size by model length)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from lfd.learning.tasks import check_whole, is_real
from lfd.planning.planner import PlannerSettings
from lfd.planning.roadmap import RoadmapSettings

__all__ = ["GROWTH_CAP", "TaskPlannerSettings", "default_vertices"]

DEFAULT_VERTICES, DEFAULT_VERTICES_STEPS = 1000, 24  # roadmap size for a model of this many steps
GROWTH_CAP = 3  # the roadmap grows after landmark moves to at most this many times its size (by default)


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
    many (None: as many as the build's biased share, ``bias_fraction`` of the roadmap size, so a
    new place gets as many sampled executions as the first, whatever the model's length: a fixed
    400 gave the 48-step pour a third as many and its plans after a bowl move poured beside the
    bowl; 40% of the roadmap still lost far-edge moves that a build for the new place pours); max_vertices: the roadmap never grows past this (default ``GROWTH_CAP`` = 3 x the roadmap size), so a long run
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
    regrow_vertices: int | None = None
    max_vertices: int | None = None
    object_radius: float = 0.13
    seed: int = 0
    roadmap: RoadmapSettings = field(default_factory=RoadmapSettings)
    planner: PlannerSettings = field(default_factory=PlannerSettings)

    def __post_init__(self):
        # whole numbers (a NumPy integer too: ``seed=np.int64(3)`` failed in torch's manual_seed) and
        # finite fractions: a float count or a NaN failed deep in torch or in a Cholesky
        for name, least in (("n_vertices", 2), ("min_free_per_step", 0), ("extra_posture_rounds", 0),
                            ("regrow_vertices", 0), ("max_vertices", 0), ("seed", 0)):
            value = getattr(self, name)
            if value is not None or name in ("min_free_per_step", "extra_posture_rounds", "seed"):
                object.__setattr__(self, name, check_whole(value, f"TaskPlannerSettings.{name}", least))
        for name in ("bias_fraction", "region_fraction", "posture_share"):
            if not is_real(getattr(self, name)) or not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"TaskPlannerSettings.{name} must be in [0, 1], got {getattr(self, name)!r}")
        for name, positive in (("region_inflation", True), ("regrow_distance", True), ("posture_spread", False),
                               ("object_radius", False)):
            value = getattr(self, name)
            if not is_real(value) or not math.isfinite(value) or value < 0 or (positive and value == 0):
                raise ValueError(f"TaskPlannerSettings.{name} must be a finite number {'> 0' if positive else '>= 0'}, "
                                 f"got {value!r}")
        if self.max_vertices is not None and self.max_vertices < max(2, self.n_vertices or 2):
            raise ValueError(f"TaskPlannerSettings.max_vertices must be None or at least n_vertices "
                             f"({self.n_vertices}) and 2, got {self.max_vertices}")
        if self.seed >= 2**63:
            raise ValueError(f"TaskPlannerSettings.seed must be a whole number in [0, 2**63), got {self.seed!r}")
        for name, kind in (("roadmap", RoadmapSettings), ("planner", PlannerSettings)):
            if not isinstance(getattr(self, name), kind):  # a dict was taken, then failed as an AttributeError
                raise TypeError(f"TaskPlannerSettings.{name} must be a {kind.__name__}, got "
                                f"{type(getattr(self, name)).__name__}")

