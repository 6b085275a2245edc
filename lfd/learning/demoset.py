"""A demonstration set in memory: ``Demonstration`` (one recording's joints and landmark poses),
``DemoSet`` (recordings that share a robot, joints, landmarks and sampling interval) and
``DemoFormatError``. Their checks are ``lfd.learning.demo_checks``; their files
``lfd.learning.demos``."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from lfd.errors import UserInputError
from lfd.learning.tasks import TaskSpec, check_stride
from lfd.robot.robots import RobotSpec

__all__ = ["DemoFormatError", "DemoSet", "Demonstration"]


class DemoFormatError(UserInputError):
    """A demonstration set that cannot be used; the message says what, where, and what is expected."""

    @classmethod
    def at(cls, where: str, what: str) -> DemoFormatError:
        """The error for ``what`` is wrong at ``where`` (a file, a demonstration, a set)."""
        return cls(f"{where}: {what}")


@dataclass(frozen=True)
class Demonstration:
    """One demonstration: ``q: (S, d)``, sampling interval ``dt``, landmarks ``(Z, 4, 4)`` (held
    still) or ``(S, Z, 4, 4)`` (tracked: the pose of each landmark at each sample)."""

    q: np.ndarray
    dt: float
    landmarks: np.ndarray
    name: str = ""

    def __post_init__(self):  # a list of rows had no .shape: n_samples raised AttributeError
        object.__setattr__(self, "q", np.asarray(self.q))
        object.__setattr__(self, "landmarks", np.asarray(self.landmarks))

    @property
    def n_samples(self) -> int:
        return int(self.q.shape[0])

    @property
    def duration(self) -> float:
        return (self.n_samples - 1) * self.dt


@dataclass(frozen=True)
class DemoSet:
    """Demonstrations that share a robot, joints, landmarks and sampling interval."""

    demos: tuple[Demonstration, ...]
    joint_names: tuple[str, ...]
    landmark_names: tuple[str, ...]
    robot: RobotSpec
    task: TaskSpec | None = None
    ground_truth: dict | None = None
    root: Path | None = None

    @property
    def dt(self) -> float:
        return self.demos[0].dt

    @property
    def n_observations(self) -> int:
        return sum(d.n_samples for d in self.demos)

    def subsample(self, stride: int) -> DemoSet:
        """Every ``stride``-th sample of each demonstration, the first included, at ``stride * dt``
        (up to ``stride - 1`` samples after the last kept one are dropped).

        The paper's remedy for densely sampled demonstrations (Sec. VI-B: the 50 Hz pour "could have
        been mitigated simply by subsampling during learning"). The task's ``dt`` is scaled with the
        samples, so a model learned from the result plans and executes at the new interval.
        The task's ``subsample`` (its default stride) becomes 1. ``stride == 1`` returns this set
        unchanged.
        """
        stride = check_stride(stride, "subsample stride")
        if stride == 1:
            return self
        demos = tuple(replace(d, q=d.q[::stride], dt=d.dt * stride,
                              landmarks=d.landmarks[::stride] if np.ndim(d.landmarks) == 4 else d.landmarks)
                      for d in self.demos)
        # the task's own learning stride is spent: the thinned set is learned from every sample
        task = replace(self.task, dt=self.task.dt * stride, subsample=1) if self.task is not None else None
        return replace(self, demos=demos, task=task)

    def landmark_index(self, name: str) -> int:
        if name not in self.landmark_names:
            raise ValueError(f"landmark {name!r} is not among {list(self.landmark_names)}")
        return self.landmark_names.index(name)
