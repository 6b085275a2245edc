"""Task definitions: what a demonstration set is a demonstration *of*.

A ``TaskSpec`` is stored as ``task.json`` beside a set of demonstrations. It carries
what the paper's baselines need and the learner never infers: the sampling interval,
the default number of time steps, the hand-picked ("manual") tool point and the
landmark a human would name as the reference (the bowl).
"""

from __future__ import annotations

import json
import math
import numbers
import re
from dataclasses import asdict, dataclass, fields
from pathlib import Path

# the feature spaces of lfd.learning.model, which a task may name, and how many world vectors each
# takes per configuration (the tool point, then the gripper's x and y axes)
TASK_VECTORS = {"paper": 1, "attitude": 3}
FEATURE_SETS = tuple(TASK_VECTORS)

__all__ = ["FEATURE_SETS", "POUR", "POWDER", "TASKS", "TASK_NAME", "TASK_VECTORS", "TaskSpec", "check_names", "check_point",
           "check_stride", "check_whole", "is_real", "task_from_name"]


TASK_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")  # a task's name is also a folder name (./runs/<task>)
# the longest sampling interval (s) a recording may have: a robot recorded at under 1 Hz is not a
# kinesthetic demonstration (a dt in milliseconds read as seconds made every simulated step last minutes)
MAX_DT = 1.0
# the longest time step (s) a task may have: a recording's interval times the stride it is learned at
MAX_STEP = 10.0
# entries task.json files once held, ignored when read: 'tool_velocity', an option measured and removed
# (docs/EXPERIMENTS.md), was written by the code of that time
RETIRED_KEYS = frozenset({"tool_velocity"})
MAX_TOOL_REACH = 2.0  # m from the gripper's origin: a hand-picked tool point farther is in other units


def is_real(value) -> bool:
    """A real number (a Python or NumPy int or float), not a bool nor a string."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def check_names(value, what: str) -> None:
    """A ``ValueError`` naming ``what`` when ``value``, which should hold several names, is one
    string (``tuple("bowl")`` would be 4 one-letter names)."""
    if isinstance(value, (str, bytes)):
        raise ValueError(f"{what} must be a list of names, got the string {value!r}")  # noqa: TRY004 (a user's value)


def check_whole(value, what: str, minimum: int = 1) -> int:
    """``value`` as an ``int`` if it is a whole number >= ``minimum`` (a Python or NumPy integer,
    not a bool nor a float), else a ``ValueError`` naming ``what``."""
    if isinstance(value, bool) or not hasattr(value, "__index__") or int(value) < minimum:
        raise ValueError(f"{what} must be a whole number >= {minimum}, got {value!r}")
    return int(value)


def check_point(value, what: str) -> tuple[float, float, float]:
    """``value`` as 3 floats if it is 3 finite real numbers (a point in metres), else a
    ``ValueError`` naming ``what``."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 3 \
            or not all(is_real(x) and math.isfinite(x)
                       for x in value):
        raise ValueError(f"{what} needs 3 finite numbers (metres), got {value!r}")
    return (float(value[0]), float(value[1]), float(value[2]))


def check_stride(value, what: str) -> int:
    """A subsampling stride (keep 1 sample in ``value``): ``check_whole(value, what, 1)``."""
    return check_whole(value, what, 1)


@dataclass(frozen=True)
class TaskSpec:
    """A task.

    Attributes
    ----------
    name : short name (``powder``, ``pour``).
    dt : sampling interval of its demonstrations, seconds.
    time_steps : default number of task-model time steps ``T``.
    manual_tool_point : the hand-picked tool point, metres, in the end-effector frame
        (the paper's "manual" tool landmark: the spoon's tip, the pitcher's spout).
    reference_landmark : the sensed landmark a person would pick (the paper's "manual"
        environment landmark).
    subsample : ``train.py`` learns the task from every ``subsample``-th sample unless told
        otherwise (``--subsample``; in Python pass ``FitConfig(subsample=task.subsample)``, whose
        own default is 1); 1 = every sample.
    features : the feature set ``train.py`` learns the task in unless told otherwise
        (``--features``; in Python ``FitConfig(features=task.features)``, whose own default is
        the paper's): 'paper' or 'attitude' (``lfd.learning.model``), where the gripper's
        attitude is the task (a pour).
    restarts : the EM restarts ``train.py`` learns the task with unless told otherwise
        (``--restarts``); None: ``FitConfig``'s default.
    """

    name: str
    dt: float
    time_steps: int = 24
    manual_tool_point: tuple[float, float, float] = (0.0, 0.0, 0.0)
    reference_landmark: str = "bowl"
    subsample: int = 1
    features: str = "paper"
    restarts: int | None = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not TASK_NAME.fullmatch(self.name):  # 'my task' no --task could name
            raise ValueError(f"TaskSpec.name must be a name of letters, digits, '_' and '-', got {self.name!r}")
        if not (is_real(self.dt) and math.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"TaskSpec.dt must be a finite positive number of seconds, got {self.dt!r}")
        if self.dt > MAX_STEP:
            raise ValueError(f"TaskSpec.dt is the time step in seconds, at most {MAX_STEP:g}; got {self.dt!r}")
        object.__setattr__(self, "dt", float(self.dt))
        object.__setattr__(self, "time_steps", check_whole(self.time_steps, "TaskSpec.time_steps", 2))
        object.__setattr__(self, "subsample", check_stride(self.subsample, "TaskSpec.subsample"))
        if self.dt * self.subsample > MAX_STEP:  # a set that train.py could only refuse
            raise ValueError(f"TaskSpec.subsample {self.subsample}: a time step of {self.dt * self.subsample:g} s "
                             f"learned, more than {MAX_STEP:g}; keep more of the samples")
        if self.restarts is not None:
            object.__setattr__(self, "restarts", check_whole(self.restarts, "TaskSpec.restarts", 1))
        object.__setattr__(self, "manual_tool_point",
                           check_point(self.manual_tool_point, "TaskSpec.manual_tool_point"))
        if math.hypot(*self.manual_tool_point) > MAX_TOOL_REACH:  # 100 m was learned with --tool manual
            raise ValueError(f"TaskSpec.manual_tool_point {list(self.manual_tool_point)} is more than "
                             f"{MAX_TOOL_REACH:g} m from the gripper (millimetres given as metres?)")
        if self.features not in FEATURE_SETS:
            raise ValueError(f"TaskSpec.features must be one of {', '.join(FEATURE_SETS)}, got {self.features!r}")
        if not isinstance(self.reference_landmark, str) or not self.reference_landmark:
            raise ValueError(f"TaskSpec.reference_landmark must be a landmark's name, got "
                             f"{self.reference_landmark!r}")

    def fit_defaults(self) -> dict:
        """The ``FitConfig`` fields a fit of this task takes from it unless told otherwise
        (``time_steps``, ``subsample``, ``features``, and ``restarts`` when the task names them)."""
        out = {"time_steps": self.time_steps, "subsample": self.subsample, "features": self.features}
        if self.restarts is not None:
            out["restarts"] = self.restarts
        return out

    def to_dict(self) -> dict:
        d = asdict(self)
        d["manual_tool_point"] = list(self.manual_tool_point)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> TaskSpec:
        """The task of ``to_dict``'s dict (``task.json``); ``ValueError`` naming the bad entry."""
        if not isinstance(d, dict):
            raise ValueError(f"a task is a JSON object, got {type(d).__name__}")  # noqa: TRY004 (bad input: a user error)
        if "name" not in d or "dt" not in d:
            raise ValueError(f"a task needs 'name' and 'dt', got keys {sorted(d)}")
        unknown = sorted(set(d) - {f.name for f in fields(cls)} - RETIRED_KEYS)
        if unknown:  # a misspelt entry would otherwise leave its setting at the default unseen
            raise ValueError(f"unknown task entries {unknown}; a task has "
                             f"{', '.join(f.name for f in fields(cls))}")
        point = d.get("manual_tool_point", (0.0, 0.0, 0.0))
        return cls(name=d["name"], dt=d["dt"], time_steps=d.get("time_steps", 24),
                   manual_tool_point=tuple(point) if isinstance(point, list) else point,
                   reference_landmark=d.get("reference_landmark", "bowl"),
                   subsample=d.get("subsample", 1), features=d.get("features", "paper"),
                   restarts=d.get("restarts"))

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> TaskSpec:
        return cls.from_dict(json.loads(Path(path).read_text()))


# The manual tool points match the tool geometry built in sim/assets.py (gripper frame).
POWDER = TaskSpec(name="powder", dt=0.1, time_steps=24, manual_tool_point=(0.0, 0.0, 0.20))
# pour: 48 steps, not the paper's 24. The pour demonstrations turn the pitcher for 2.4 s, hold it
# 1.2-2 s and turn it back (about 6 s of ~16 s); with 24 steps a step spans turning and holding,
# its mean posture is rolled ~90 degrees, and the pitcher needs ~100 to empty (README, "Learning").
# Learned at 25 Hz (every 2nd sample of the 50 Hz demonstrations), the paper's remedy for its
# 50 Hz pour (Sec. VI-B): at 50 Hz hard EM lets one demonstration dwell in a step for 100-200
# samples while the others pass through it in one (README, "Learning": measured against 10 Hz).
# Learned with the gripper's attitude (features='attitude'): in the paper's feature space the plans
# tilted the pitcher 7-13 deg less than the demonstrations (the roll is cheap in the learned joint
# metric) and poured 75-83% for two of three demonstration draws (docs/EXPERIMENTS.md, issue 24).
# 4 EM restarts, not FitConfig's 12: a restart of the pour (about 4,600 observations at 25 Hz, 48
# steps) takes 4-5 s, and with 4 the pour reached 98% / 98% / 90% on three demonstration draws
# (docs/RESULTS.md) in 18-22 s of learning.
POUR = TaskSpec(name="pour", dt=0.02, time_steps=48, manual_tool_point=(-0.08, 0.07, 0.135), subsample=2,
                features="attitude", restarts=4)

TASKS = {t.name: t for t in (POWDER, POUR)}


def task_from_name(name: str) -> TaskSpec:
    if name not in TASKS:
        raise ValueError(f"unknown task {name!r}; expected one of: {', '.join(TASKS)}")
    return TASKS[name]
