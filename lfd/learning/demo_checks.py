"""What a demonstration set must satisfy to be learned from, however it was made.

Two kinds of check. The first says why recordings are unusable beyond their format (landmarks in
other units or frames, tracked landmarks that jump, an arm that never moves, one recording twice,
a task at another interval): each returns why (one sentence) or ``None``, and ``lfd.io.recordings``
(CSV recordings) raises its own errors with it. The second checks a ``DemoSet``'s arrays, names,
robot and joint limits and raises ``DemoFormatError`` naming where: ``check_demoset`` for a set
built in Python, and the pieces ``lfd.learning.demos`` uses on the arrays of ``.npz`` files."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from lfd.learning.demoset import DemoFormatError, Demonstration, DemoSet
from lfd.learning.tasks import MAX_DT, TaskSpec, is_real
from lfd.robot.robots import RobotSpec
from lfd.robot.se3 import not_rigid, rigid_errors

__all__ = [
    "LIMIT_TOLERANCE",
    "MAX_LANDMARK_DISTANCE",
    "MAX_LANDMARK_SPEED",
    "MIN_JOINT_TRAVEL",
    "check_demonstration",
    "check_demoset",
    "check_limit_tolerance",
    "check_same_dt",
    "check_set",
    "far_landmark",
    "jumping_landmark",
    "names_from_array",
    "other_task_dt",
    "same_interval",
    "unusable_demos",
]

MAX_LANDMARK_DISTANCE = 20.0  # m from the robot's base: a landmark farther was given in other units
MAX_LANDMARK_SPEED = 5.0  # m/s: a tracked landmark faster than this between samples is a tracking glitch
MIN_JOINT_TRAVEL = 0.01  # rad: a demonstration in which no joint moves more than this shows no motion
LIMIT_TOLERANCE = 0.02  # rad: recorded joints may sit this far outside the URDF limits


def far_landmark(poses: np.ndarray, names: Sequence[str]) -> str | None:
    """Why landmark poses ``(Z, 4, 4)`` or, tracked, ``(S, Z, 4, 4)`` cannot be metres in the
    robot's base frame (a landmark farther than ``MAX_LANDMARK_DISTANCE`` from it), or ``None``."""
    dist = np.linalg.norm(poses[..., :3, 3], axis=-1)  # (Z,) or (S, Z)
    if dist.size == 0 or float(dist.max()) <= MAX_LANDMARK_DISTANCE:
        return None
    idx = np.unravel_index(int(np.argmax(dist)), dist.shape)
    at = f" at sample {int(idx[0])}" if dist.ndim == 2 else ""
    return (f"landmark {names[int(idx[-1])]!r} is {float(dist[idx]):.4g} m from the robot's base{at}, more than "
            f"{MAX_LANDMARK_DISTANCE:g} m (millimetres given as metres, or another frame than the base's?)")


def jumping_landmark(poses: np.ndarray, names: Sequence[str], dt: float | np.ndarray) -> str | None:
    """Why tracked landmark poses ``(S, Z, 4, 4)``, sampled every ``dt`` s (a number, or the
    ``(S - 1,)`` intervals of readings at their own times), cannot be one object's motion (a
    landmark faster than ``MAX_LANDMARK_SPEED`` between two samples), or ``None``; ``None`` for
    landmarks held still ``(Z, 4, 4)``."""
    if poses.ndim != 4 or poses.shape[0] < 2:
        return None
    step = np.linalg.norm(np.diff(poses[:, :, :3, 3], axis=0), axis=-1)  # (S - 1, Z) m
    speed = step / np.broadcast_to(np.reshape(np.asarray(dt, dtype=float), (-1, 1)), step.shape)
    if float(speed.max()) <= MAX_LANDMARK_SPEED:
        return None
    s, z = (int(i) for i in np.unravel_index(int(np.argmax(speed)), speed.shape))
    return (f"landmark {names[z]!r} moves {float(step[s, z]):.3g} m between samples {s} and {s + 1} "
            f"({float(speed[s, z]):.3g} m/s, more than {MAX_LANDMARK_SPEED:g} m/s: a tracking glitch, or "
            f"another marker read as this landmark?)")


def same_interval(dt: float, dt0: float) -> bool:
    """Whether two sampling intervals (s) are the same, but for rounding: within one part in a
    million, wider than float32's rounding (``np.float32(0.1)`` is 0.10000000149), so that an
    interval stored in single precision matches its ``task.json``."""
    return abs(dt - dt0) <= 1e-6 * max(abs(dt), abs(dt0))


def other_task_dt(task_dt: float, dt: float) -> str | None:
    """Why a task whose ``dt`` is ``task_dt`` cannot be the task of demonstrations sampled every
    ``dt`` s (a learned model's time step is its task's ``dt``, the samples' own interval), or
    ``None``."""
    if same_interval(task_dt, dt):
        return None
    return (f"dt={task_dt} differs from the demonstrations' sampling interval dt={dt} (the model's dt comes "
            f"from the task)")


def unusable_demos(qs: Sequence[np.ndarray], names: Sequence[str]) -> str | None:
    """Why demonstrations with joint trajectories ``qs`` (each ``(S, d)``) and ``names`` cannot be
    learned from as they are, or ``None``: one in which no joint travels ``MIN_JOINT_TRAVEL``
    (the arm never moved: a recording that missed the motion), or two with the same joint
    trajectory (one recording saved twice would count twice in the model)."""
    for i, (q, name) in enumerate(zip(qs, names)):
        travel = float(np.ptp(q, axis=0).max()) if len(q) else 0.0
        if travel < MIN_JOINT_TRAVEL:
            return (f"demonstration {name or i!r}: no joint moves more than {travel:.2g} rad: the arm never "
                    f"moved (at least {MIN_JOINT_TRAVEL:g} rad is expected of a demonstration)")
        for q0, name0 in zip(qs[:i], names[:i]):
            if q0.shape == q.shape and np.array_equal(q0, q):
                return (f"demonstrations {name0!r} and {name!r} have the same joint trajectory: one "
                        f"recording twice? (each would count as a demonstration of its own)")
    return None


def _as_float(where: str, key: str, value, ndim: int) -> np.ndarray:
    if value.dtype.kind not in "fiu":
        raise DemoFormatError.at(where, f"key {key!r} must be numeric, got dtype {value.dtype}")
    value = value.astype(np.float64)
    if value.ndim != ndim:
        raise DemoFormatError.at(where, f"key {key!r} must have {ndim} dimension(s), got shape {value.shape}")
    if not np.all(np.isfinite(value)):
        bad = np.argwhere(~np.isfinite(value))[0].tolist()
        raise DemoFormatError.at(where, f"key {key!r} holds NaN or infinite values (first at index {bad})")
    return value


def names_from_array(where: str, key: str, value) -> tuple[str, ...]:
    """The names held by ``value``, a 1-D array of strings (bytes decoded as UTF-8), each
    non-empty and none repeated; ``DemoFormatError`` naming ``where`` and ``key`` otherwise."""
    if value.dtype.kind not in "US" or value.ndim != 1:
        raise DemoFormatError.at(where, f"key {key!r} must be a 1-D array of strings, got dtype {value.dtype} "
                                        f"and shape {value.shape}")
    try:  # bytes (dtype S, e.g. written by Python 2 or h5py) are decoded, not shown as "b'...'"
        names = tuple(v.decode("utf-8") if isinstance(v, bytes) else str(v) for v in value.tolist())
    except UnicodeDecodeError as e:
        raise DemoFormatError.at(where, f"key {key!r} holds bytes that are not UTF-8 text ({e})") from e
    if len(set(names)) != len(names):
        raise DemoFormatError.at(where, f"key {key!r} repeats a name: {list(names)}")
    if not all(n.strip() for n in names):  # '  ' was a name no option could give
        raise DemoFormatError.at(where, f"key {key!r} holds an empty name: {list(names)}")
    return names


def _landmark_poses(where: str, value, names: tuple, n_samples: int, dt: float) -> np.ndarray:
    """``landmark_poses`` checked: ``(Z, 4, 4)`` or ``(S, Z, 4, 4)`` (tracked, one pose per sample
    every ``dt`` s), finite and rigid, ``Z`` the names' count, metres in the base frame, tracked
    ones moving as an object can (``far_landmark``, ``jumping_landmark``)."""
    shape = f"({len(names)}, 4, 4) or, tracked, ({n_samples}, {len(names)}, 4, 4)"
    if value.dtype.kind not in "fiu" or value.ndim not in (3, 4):
        raise DemoFormatError.at(where, f"key 'landmark_poses' must be numeric of shape {shape} to match "
                                        f"'landmark_names' and 'q', got dtype {value.dtype} and shape {value.shape}")
    poses = _as_float(where, "landmark_poses", value, value.ndim)
    if poses.shape[-3:] != (len(names), 4, 4) or (poses.ndim == 4 and poses.shape[0] != n_samples):
        raise DemoFormatError.at(where, f"key 'landmark_poses' must have shape {shape} to match 'landmark_names' "
                                        f"and 'q', got {poses.shape}")
    if poses.shape[-3] == 0:
        raise DemoFormatError.at(where, "no sensed landmarks: 'landmark_poses' is empty")
    bad = np.argwhere(not_rigid(poses))
    if bad.size:
        idx = tuple(int(x) for x in bad[0])
        ortho, det, bottom = rigid_errors(poses[idx])
        at = f" at sample {idx[0]}" if poses.ndim == 4 else ""
        raise DemoFormatError.at(where, f"landmark {names[idx[-1]]!r} pose{at} is not a rigid transform "
                                        f"(|R^T R - I| = {ortho:.2g}, |det R - 1| = {det:.2g}, "
                                        f"bottom row error {bottom:.2g})")
    why = far_landmark(poses, names) or jumping_landmark(poses, names, dt)
    if why:
        raise DemoFormatError.at(where, why)
    return poses


def check_demonstration(where: str, demo: Demonstration, joint_names, landmark_names) -> Demonstration:
    """``demo`` checked on its own against its set's names (``where`` starts each message): ``q``
    finite ``(S, d)``, S >= 2, one column per joint name; ``dt`` in ``(0, MAX_DT]``; its landmark poses
    as ``_landmark_poses`` checks them. Returned with float64 arrays. The checks of a file's
    arrays (``load_demos``) and of a ``DemoSet`` built in Python (``check_demoset``)."""
    q = _as_float(where, "q", np.asarray(demo.q), 2)
    if q.shape[1] != len(joint_names):
        raise DemoFormatError.at(where, f"key 'q' has {q.shape[1]} columns but 'joint_names' names {len(joint_names)} "
                                        f"joints")
    if len(q) < 2:  # (no motion; a set's loader said so only against the model's time steps)
        raise DemoFormatError.at(where, f"key 'q' has {len(q)} sample(s); a demonstration needs at least 2")
    dt = _as_float(where, "dt", np.asarray(demo.dt), 0)
    if not 0 < dt <= MAX_DT:
        hint = " (milliseconds given as seconds?)" if dt > MAX_DT else ""
        raise DemoFormatError.at(where, f"key 'dt' (sampling interval, seconds) must be positive and at most "
                                        f"{MAX_DT:g}, got {float(dt)}{hint}")
    poses = _landmark_poses(where, np.asarray(demo.landmarks), tuple(landmark_names), len(q), float(dt))
    return Demonstration(q=q, dt=float(dt), landmarks=poses, name=demo.name)


def _check_limits(where: str, q: np.ndarray, joint_names, lower, upper, tol: float) -> None:
    below = q < lower - tol
    above = q > upper + tol
    if below.any() or above.any():
        s, j = np.argwhere(below | above)[0]
        raise DemoFormatError.at(where, f"sample {s}, joint {joint_names[j]!r} = {q[s, j]:.4f} rad is outside its "
                                        f"limits [{lower[j]:.4f}, {upper[j]:.4f}] (tolerance {tol} rad)")


def check_same_dt(where: str, dt: float, first: str, dt0: float) -> None:
    """``DemoFormatError`` at ``where`` when its interval ``dt`` is not ``first``'s ``dt0``."""
    if not same_interval(dt, dt0):
        raise DemoFormatError.at(where, f"sampling interval dt={dt} differs from {first}'s dt={dt0}")


def check_limit_tolerance(limit_tolerance) -> float:
    """``limit_tolerance`` as a float if it is a finite angle >= 0 (NaN turned the limit check off)."""
    if not (is_real(limit_tolerance) and math.isfinite(limit_tolerance) and limit_tolerance >= 0):
        raise ValueError(f"limit_tolerance must be a finite angle >= 0 (rad), got {limit_tolerance!r}")
    return float(limit_tolerance)


def check_set(demos, wheres: list[str], joint_names: tuple, robot: RobotSpec, task: TaskSpec | None,
               set_where: str, names_where: str, task_where: str, kin, limit_tolerance: float):
    """What a set's demonstrations, each checked on its own and with one ``dt``, must satisfy
    together with their robot and task: the task's ``dt`` is theirs, the joint names are the
    robot's in its order, ``kin`` (built from ``robot`` when None) is the robot's, every sample
    is within its joint limits (``limit_tolerance`` rad), and they can be learned from
    (``unusable_demos``). Returns ``kin``. ``load_demos`` and ``check_demoset``; ``wheres`` name
    the demonstrations in messages, ``set_where`` the set, ``names_where`` its joint names and
    ``task_where`` its task."""
    why = other_task_dt(task.dt, demos[0].dt) if task is not None else None
    if why:
        raise DemoFormatError.at(task_where, why)
    unknown = [n for n in joint_names if n not in robot.joint_names]
    if unknown:
        raise DemoFormatError.at(names_where, f"unknown joint name(s) {unknown}; robot {robot.name!r} has "
                                            f"{list(robot.joint_names)}")
    if joint_names != robot.joint_names:
        raise DemoFormatError.at(names_where, f"joint_names must be {list(robot.joint_names)} in this order, got "
                                            f"{list(joint_names)}")
    if kin is None:
        from lfd.robot.kinematics import KinematicModel, KinematicsError
        try:
            kin = KinematicModel.from_spec(robot)
        except KinematicsError as e:
            raise DemoFormatError.at(names_where, f"robot {robot.name!r} cannot be loaded: {e}") from e
    elif tuple(kin.joint_names) != robot.joint_names or kin.end_link != robot.end_link:
        raise DemoFormatError.at(set_where, f"the kinematic model (kin) is of joints {list(kin.joint_names)} to "
                                            f"{kin.end_link!r}, not of the demonstrations' robot {robot.name!r} "
                                            f"(joints {list(robot.joint_names)} to {robot.end_link!r})")
    lower, upper = kin.lower.cpu().numpy(), kin.upper.cpu().numpy()
    for where, d in zip(wheres, demos):
        _check_limits(where, d.q, joint_names, lower, upper, limit_tolerance)
    why = unusable_demos([d.q for d in demos], [d.name for d in demos])
    if why:
        raise DemoFormatError.at(set_where, why)
    return kin


def check_demoset(demoset: DemoSet, kin=None, limit_tolerance: float = LIMIT_TOLERANCE) -> tuple[DemoSet, object]:
    """A ``DemoSet`` however it was made (built in Python, ``lfd.io.recordings``) checked as
    ``load_demos`` checks a set's files: each demonstration (``check_demonstration``), one ``dt``,
    the task, the robot and ``kin`` (``check_set``). Returns the set with float64 arrays and
    ``kin`` (built from ``demoset.robot`` when None); ``DemoFormatError`` naming the
    demonstration otherwise. ``lfd.learning.learn.fit`` calls it on what it is given."""
    limit_tolerance = check_limit_tolerance(limit_tolerance)
    if not isinstance(demoset, DemoSet):
        raise TypeError(f"expected a DemoSet (lfd.learning.demoset), got {type(demoset).__name__}")
    if not isinstance(demoset.robot, RobotSpec):
        raise DemoFormatError.at("the DemoSet", f"robot must be a RobotSpec, got {type(demoset.robot).__name__}")
    if isinstance(demoset.demos, (str, bytes)) or not len(demoset.demos):
        raise DemoFormatError.at("the DemoSet", "no demonstrations")
    joint_names = names_from_array("the DemoSet", "joint_names", np.asarray(demoset.joint_names))
    landmark_names = names_from_array("the DemoSet", "landmark_names", np.asarray(demoset.landmark_names))
    wheres = [f"demonstration {d.name!r}" if getattr(d, "name", "") else f"demonstration {i}"
              for i, d in enumerate(demoset.demos)]
    demos: list[Demonstration] = []
    for where, d in zip(wheres, demoset.demos):
        demo = check_demonstration(where, d, joint_names, landmark_names)
        if demos:
            check_same_dt(where, demo.dt, demos[0].name or "demonstration 0", demos[0].dt)
        demos.append(demo)
    kin = check_set(demos, wheres, joint_names, demoset.robot, demoset.task, "the DemoSet", "the DemoSet",
                     "the DemoSet's task", kin, limit_tolerance)
    return replace(demoset, demos=tuple(demos), joint_names=joint_names, landmark_names=landmark_names), kin
