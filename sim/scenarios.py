"""Seeded test scenarios, drawn as in the paper's evaluation (Sec. VI).

Drawing rule (also stated in the README):

* the bowl is uniform in the 30-inch square (``layout.SQUARE_*``), at least
  ``MIN_BOWL_SOURCE`` from the source container so the task has a carrying phase;
* the **paper-towel roll** stands on the carrying line from the source container to the
  bowl, a uniform fraction ``[0.35, 0.65]`` of the way, shifted sideways by at most 4 cm: a
  motion that carries the tool straight over to the bowl runs into it;
* the **lamp shade** hangs above the carrying line (a uniform fraction ``[0.3, 0.8]`` of the
  way, 5 cm sideways at most), its lower rim ``LAMP_BOTTOM_RANGE`` above the table: the
  height through which the arm lifts and carries the tool;
* ``powder``: the bowl moves during the task (when the executed time step reaches a quarter of
  the model's T steps, ``MOVE_AT``, while the spoon is being carried towards it, before the
  dump) to a second uniform place in the square at least ``MIN_MOVE`` away;
  the four distractor markers are uniform in the square, lifted ``layout.MARKER_HEIGHT...``;
* ``pour``: the vase, the scissors, the spoon and the (landmark) paper-towel roll are the
  other sensed landmarks; vase and scissors/spoon are uniform in the square; the bowl stays
  (the reaction benchmark moves it by the powder's rule: ``with_bowl_move``);
* scenarios that no plan could solve are not drawn: an obstacle closer than
  ``CLEARANCE`` to the bowl (at either place) or to the source container is redrawn, and so
  is anything off the table; so is a scene where the arm cannot hold the tool as the
  demonstrator does to dump or pour over the bowl (at either place) without touching an
  obstacle, for any bearing within 30 deg of the demonstrator's (``sim.reach.DumpReach``:
  seeded IK and the planner's collision check; a low lamp shade between the shoulder and a
  far bowl does that), and so is a scene where the arm's start configuration (``layout.HOME_Q``)
  touches an object (a vase against the forearm). No learned model takes part in the drawing.

The same ``(task, seed)`` always gives the same scenario; scenario ``i`` of a set with base
seed ``S`` uses seed ``S * 100_003 + i``.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from lfd.errors import UserInputError
from sim import layout as L

SEED_STRIDE = 100_003  # scenario i of the set with base seed S has seed S * SEED_STRIDE + i
# a scenario's seed seeds numpy and torch (the planner's draws): both take [0, 2**63)
MAX_SCENARIO_SEED = 2**63
MAX_BASE_SEED = MAX_SCENARIO_SEED // SEED_STRIDE - 1

__all__ = [
    "CLEARANCE",
    "FOOTPRINT",
    "ITEM_RADIUS",
    "MAX_BASE_SEED",
    "MAX_SCENARIO_SEED",
    "MIN_BOWL_SOURCE",
    "MOVE_AT",
    "SEED_STRIDE",
    "SOURCE_RADIUS",
    "Scenario",
    "check_set_size",
    "draw_scenario",
    "draw_scenarios",
    "with_bowl_move",
]

MIN_BOWL_SOURCE = 0.30       # m, bowl centre to source container centre
MIN_MOVE = 0.20              # m, how far the bowl moves in the powder closed-loop test
MOVE_AT = 0.25               # the share of the task's time steps after which it moves (the spoon is being carried)
CLEARANCE = 0.10             # m, free gap between an obstacle's and the bowl's / source's outline
LAMP_BOTTOM_RANGE = (0.42, 0.55)  # m above the table top: at the height of the elbow and upper arm
MAX_TRIES = 10_000
ITEM_RADIUS = 0.08           # m, footprint of the scissors and the spoon lying on the table (pour)
# footprint radius (m) of each object an obstacle-free place must keep CLEARANCE from
FOOTPRINT = {"paper_towels": L.PAPER_TOWELS_RADIUS, "vase": L.VASE_RADIUS, "scissors": ITEM_RADIUS,
             "spoon": ITEM_RADIUS}
SOURCE_RADIUS = float(np.hypot(*L.SOURCE_HALF_XY))  # m, the source container's footprint


@dataclass(frozen=True)
class Scenario:
    """One test scene.

    ``placements``: object name -> ``(x, y)`` on the table or ``(x, y, z)`` base position.
    ``bowl_after``: where the bowl moves (``powder``; the reaction benchmark gives the pour's
    scenes one too, ``with_bowl_move``), applied when the executed time step reaches
    ``move_at`` times the model's time steps T (a share of the task, so that one scene means the
    same moment for models of any T: ``move_step``); None for no move.
    """

    task: str
    seed: int
    placements: dict = field(default_factory=dict)
    bowl_after: tuple | None = None
    move_at: float | None = None

    def __post_init__(self):
        if (self.move_at is None) != (self.bowl_after is None):
            raise ValueError("a scenario's bowl_after and move_at are given together or not at all")
        if self.move_at is not None and not 0.0 <= self.move_at < 1.0:  # (NaN too)
            raise ValueError(f"move_at is a share of the task in [0, 1), got {self.move_at}")

    def move_step(self, time_steps: int) -> int | None:
        """The time step (of a model with ``time_steps`` steps) at which the bowl moves; None
        without a move."""
        if isinstance(time_steps, bool) or not isinstance(time_steps, numbers.Integral) or time_steps < 1:
            raise ValueError(f"time_steps must be a whole number >= 1, got {time_steps!r}")
        return None if self.move_at is None else int(math.floor(self.move_at * time_steps + 1e-9))

    def to_dict(self) -> dict:
        return {"task": self.task, "seed": self.seed,
                "placements": {k: [float(x) for x in v] for k, v in self.placements.items()},
                "bowl_after": None if self.bowl_after is None else [float(x) for x in self.bowl_after],
                "move_at": self.move_at}


def _in_square(rng) -> np.ndarray:
    c = np.asarray(L.SQUARE_CENTER_XY)
    return c + rng.uniform(-L.SQUARE_HALF, L.SQUARE_HALF, 2)


def _on_table(xy, margin: float) -> bool:
    c, h = np.asarray(L.TABLE_CENTER_XY), np.asarray(L.TABLE_HALF_XY)
    return bool(np.all(np.abs(np.asarray(xy) - c) <= h - margin))


def _on_line(rng, a, b, frac_range, max_side) -> np.ndarray:
    d = b - a
    normal = np.array([-d[1], d[0]]) / max(np.linalg.norm(d), 1e-9)
    return a + rng.uniform(*frac_range) * d + rng.uniform(-max_side, max_side) * normal


def _clear(xy, radius, others) -> bool:
    """``xy`` with ``radius`` keeps ``CLEARANCE`` from every ``(centre, radius)`` in others."""
    return all(np.linalg.norm(np.asarray(xy) - np.asarray(c)) >= radius + r + CLEARANCE for c, r in others)


def _bowl_move_ok(after, bowl, source) -> bool:
    """The powder's rule for the bowl's second place: ``MIN_MOVE`` from the first, and
    ``MIN_BOWL_SOURCE`` from the source container."""
    return bool(np.linalg.norm(after - bowl) >= MIN_MOVE and np.linalg.norm(after - source) >= MIN_BOWL_SOURCE)


def draw_scenario(task: str, seed: int, reach=None) -> Scenario:
    """The scenario of ``(task, seed)``; see the module docstring for the rule.

    ``reach``: a ``sim.reach.DumpReach`` of ``task`` to reuse (one is made and closed here when
    None); it never changes which scenario a seed gives.
    """
    if task not in ("powder", "pour"):
        raise ValueError(f"task must be 'powder' or 'pour', got {task!r}")
    if reach is None:
        from sim.reach import DumpReach
        with DumpReach(task) as own:
            return draw_scenario(task, seed, own)
    if reach.task != task:
        raise ValueError(f"reach checks the {reach.task!r} task, not {task!r}")
    rng = np.random.default_rng(seed)
    source = np.asarray(L.SOURCE_DEFAULT_XY, dtype=float)
    bowl_r = L.BOWL_RADIUS + L.BOWL_WALL
    towel_r = FOOTPRINT["paper_towels"]
    for _ in range(MAX_TRIES):
        bowl = _in_square(rng)
        if np.linalg.norm(bowl - source) < MIN_BOWL_SOURCE:
            continue
        bowls = [(bowl, bowl_r)]
        bowl_after = None
        if task == "powder":
            bowl_after = _in_square(rng)
            if not _bowl_move_ok(bowl_after, bowl, source):
                continue
            bowls.append((bowl_after, bowl_r))
        keep_out = bowls + [(source, SOURCE_RADIUS)]
        towels = _on_line(rng, source, bowl, (0.35, 0.65), 0.04)
        if not (_on_table(towels, towel_r) and _clear(towels, towel_r, keep_out)):
            continue
        lamp = _on_line(rng, source, bowl, (0.3, 0.8), 0.05)
        if not _on_table(lamp, 0.0):
            continue
        lamp_z = L.TABLE_TOP_Z + rng.uniform(*LAMP_BOTTOM_RANGE)
        placements = {"bowl": tuple(bowl), "paper_towels": tuple(towels),
                      "lamp_shade": (float(lamp[0]), float(lamp[1]), float(lamp_z))}
        ok = True
        if task == "powder":
            for i in range(1, 5):
                m = _in_square(rng)
                placements[f"marker_{i}"] = (float(m[0]), float(m[1]),
                                             L.TABLE_TOP_Z + L.MARKER_HEIGHT_ABOVE_TABLE)
        else:
            taken = keep_out + [(towels, towel_r)]
            for name in ("vase", "scissors", "spoon"):
                r = FOOTPRINT[name]
                xy = _in_square(rng)
                if not (_on_table(xy, r) and _clear(xy, r, taken)):
                    ok = False
                    break
                placements[name] = tuple(xy)
                taken.append((xy, r))
        if not ok or not reach.start_free(placements) or not all(reach(placements, b) for b, _ in bowls):
            continue
        return Scenario(task=task, seed=int(seed), placements=placements,
                        bowl_after=None if bowl_after is None else tuple(bowl_after),
                        move_at=MOVE_AT if bowl_after is not None else None)
    raise RuntimeError(f"could not draw a solvable {task} scenario for seed {seed}")


def check_set_size(n: int, name: str = "the number of scenarios") -> int:
    """``n`` if it is a scenario set's size, in [1, ``SEED_STRIDE``]: more would give two sets the
    same scenes (scenario ``S * SEED_STRIDE + i`` would be another set's too). Otherwise
    ``lfd.errors.UserInputError`` (a ``ValueError``; one line and exit status 2 in a command) naming
    ``name``."""
    if n < 1:
        raise UserInputError(f"{name} must be at least 1, got {n}")
    if n > SEED_STRIDE:
        raise UserInputError(f"{name} must be at most {SEED_STRIDE} (the seeds' stride between scenario sets: "
                             f"more would give two sets the same scenes), got {n}")
    return n


def draw_scenarios(task: str, n: int, base_seed: int = 0, reach=None) -> list[Scenario]:
    """``n`` scenarios of a set with ``base_seed`` (``reach``: as in ``draw_scenario``)."""
    check_set_size(n)
    if reach is None:
        from sim.reach import DumpReach
        with DumpReach(task) as own:
            return draw_scenarios(task, n, base_seed, own)
    return [draw_scenario(task, base_seed * SEED_STRIDE + i, reach) for i in range(n)]


def with_bowl_move(scenario: Scenario, reach=None) -> Scenario:
    """``scenario`` with a mid-task bowl move when it has none (the pour's evaluation scenes keep
    the bowl still; the reaction benchmark moves it in both tasks): a second place drawn as the
    powder's (uniform in the square, at least ``MIN_MOVE`` away, ``MIN_BOWL_SOURCE`` from the
    source container), ``CLEARANCE`` from every object on the table, where the arm can hold the
    tool over the bowl (``reach``, a ``sim.reach.DumpReach`` of the task), at ``MOVE_AT`` of the task. Seeded by
    the scenario's seed (its own stream): the same scenario always gets the same move."""
    if scenario.bowl_after is not None:
        return scenario
    if reach is None:
        from sim.reach import DumpReach
        with DumpReach(scenario.task) as own:
            return with_bowl_move(scenario, own)
    if reach.task != scenario.task:
        raise ValueError(f"reach checks the {reach.task!r} task, not {scenario.task!r}")
    rng = np.random.default_rng([int(scenario.seed), 1])
    source = np.asarray(L.SOURCE_DEFAULT_XY, dtype=float)
    bowl = np.asarray(scenario.placements["bowl"], dtype=float)
    bowl_r = L.BOWL_RADIUS + L.BOWL_WALL
    others = [(np.asarray(scenario.placements[n][:2], dtype=float), r) for n, r in FOOTPRINT.items()
              if n in scenario.placements] + [(source, SOURCE_RADIUS)]
    for _ in range(MAX_TRIES):
        after = _in_square(rng)
        if not (_bowl_move_ok(after, bowl, source) and _clear(after, bowl_r, others)
                and reach(scenario.placements, after)):
            continue
        return Scenario(task=scenario.task, seed=scenario.seed, placements=dict(scenario.placements),
                        bowl_after=tuple(after), move_at=MOVE_AT)
    raise RuntimeError(f"could not draw a bowl move for the {scenario.task} scenario of seed {scenario.seed}")
