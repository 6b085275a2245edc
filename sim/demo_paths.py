"""Task-point paths of the kinesthetic demonstrator (pure numpy; no PyBullet, no IK).

A demonstration is a sequence of keyframes of the *tool frame*: the gripper frame's orientation
with its origin moved to the hidden task point. Each keyframe holds the task point's world
position and three angles:

* ``yaw``: the facing direction (the tool's pointing axis, gripper z, projected on the table);
* ``pitch``: rotation about gripper x that tips the tool's far end up or down (a few degrees);
* ``roll``: rotation about gripper z, the tool's long axis (turning the spoon over, tipping the
  pitcher's spout, on its -x side, down).

``R_world_tool = R_level(yaw) @ R_x(pitch) @ R_z(roll)``, where ``R_level`` has gripper z
horizontal along ``yaw`` and gripper y (the tool's "up", see ``sim.layout``) equal to world +z.

Keyframes near the bowl are placed relative to the bowl (world-aligned, at the bowl's base
frame: the centre of its bottom); the start and the end are relative to the source container.
A demonstration's timing maps time to a phase ``u`` (keyframe ``k`` at ``u = k``) through a
monotone PCHIP with per-segment random durations and pauses; positions and angles are PCHIP
functions of ``u``. All randomness comes from the ``numpy.random.Generator`` passed in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator

from sim import layout as L

__all__ = [
    "DUMP_NOMINAL",
    "SHOULDER_XY",
    "TASK_POINTS",
    "DemoPath",
    "bowl_frame_path",
    "check_roll",
    "draw_path",
    "dump_pose",
    "rotation_level",
    "tool_rotation",
]

# Default hidden task points, metres in the gripper frame (see sim.layout for the tools):
# powder -- the centre of the scoop just above its floor, on the spoon's long axis, i.e. the
# point the dumping roll turns about; pour -- a point just below the spout lip (-x side).
TASK_POINTS = {"powder": (0.0, 0.01, 0.17), "pour": (-0.07, 0.045, 0.135)}
SHOULDER_XY = (0.064, 0.259)  # left_upper_shoulder above the base, for the facing direction
KEYS = ("x", "y", "z", "yaw", "pitch", "roll")


def rotation_level(yaw: float) -> np.ndarray:
    """``R_world_tool`` of a level tool pointing along ``yaw``: columns x, y (= world up), z."""
    z = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    y = np.array([0.0, 0.0, 1.0])
    return np.stack([np.cross(y, z), y, z], axis=1)


def tool_rotation(yaw, pitch, roll) -> np.ndarray:
    """``(S,) x3 -> (S, 3, 3)``: ``R_level(yaw) @ R_x(pitch) @ R_z(roll)``."""
    yaw, pitch, roll = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (yaw, pitch, roll))
    out = np.empty((len(yaw), 3, 3))
    for i, (a, b, c) in enumerate(zip(yaw, pitch, roll)):
        cb, sb, cc, sc = np.cos(b), np.sin(b), np.cos(c), np.sin(c)
        Rx = np.array([[1, 0, 0], [0, cb, -sb], [0, sb, cb]])
        Rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
        out[i] = rotation_level(a) @ Rx @ Rz
    return out


@dataclass(frozen=True)
class DemoPath:
    """A sampled demonstration path.

    Attributes
    ----------
    t : (S,) sample times, s (``t[i] = i * dt``).
    T_world_tool : (S, 4, 4) target poses of the tool frame (origin at the task point).
    u : (S,) phase (keyframe index, fractional).
    keyframes : (K, 6) the keyframes (x, y, z, yaw, pitch, roll).
    bowl_xy : (2,) bowl position.
    """

    t: np.ndarray
    T_world_tool: np.ndarray
    u: np.ndarray
    keyframes: np.ndarray
    bowl_xy: np.ndarray

    @property
    def duration(self) -> float:
        return float(self.t[-1])


# Near the body the left arm reaches across and a person turns the tool towards the right:
# the facing turns clockwise from the shoulder->bowl bearing by up to NEAR_TURN, linearly from
# NEAR_FAR[1] down to NEAR_FAR[0] metres from the shoulder. Measured with IK (64 random seeds,
# self and table collision): pointing along the bearing, a level spoon 0.12-0.28 m above the
# table at x = 0.46 has no collision-free solution (the forearm hits the torso); turned 30-60
# degrees clockwise, most solutions are free. Far away (>= 0.85 m) only the bearing is reachable.
NEAR_TURN = np.deg2rad(45.0)
POUR_THROW = 0.08
NEAR_FAR = (0.5, 0.85)


def facing(bowl_xy) -> float:
    """The nominal yaw over the bowl: the bearing from the shoulder, turned right near the body."""
    dx, dy = bowl_xy[0] - SHOULDER_XY[0], bowl_xy[1] - SHOULDER_XY[1]
    near = np.clip((NEAR_FAR[1] - np.hypot(dx, dy)) / (NEAR_FAR[1] - NEAR_FAR[0]), 0.0, 1.0)
    return float(np.arctan2(dy, dx) - NEAR_TURN * near)


def _pour_aim(yaw: float, pitch: float, roll: float, tool_point) -> np.ndarray:
    """``(2,)`` shift of the pouring task point from the bowl's centre, on the table.

    A person aims the stream, not the task point: the liquid leaves between the spout lip and
    the centre of the cup's open top; that point goes over the bowl's centre when turned, and
    (measured in replays) the stream reaches the rim's height ``POUR_THROW`` further out along
    the spout's horizontal direction (gripper -x when level) than that point.
    """
    exit_pt = 0.5 * (np.array(L.PITCHER_SPOUT_LIP) + [0.0, L.PITCHER_RIM_Y, L.PITCHER_AXIS_Z])
    R_t = tool_rotation(yaw, pitch, roll)[0]
    return -(R_t @ (exit_pt - np.asarray(tool_point)))[:2] + POUR_THROW * np.array([-np.sin(yaw), np.cos(yaw)])


# the demonstrator's nominal pose while dumping / pouring: task-point height above the bowl's
# rim (m) and the roll (deg); _keyframes draws the roll within +-ROLL_SPREAD of it
DUMP_NOMINAL = {"powder": (0.055, 120.0), "pour": (0.135, 115.0)}
ROLL_SPREAD = {"powder": 10.0, "pour": 8.0}


def check_roll(roll_deg) -> float | None:
    """A demonstrator's nominal roll (deg) checked: None (the task's, ``DUMP_NOMINAL``) or a
    finite number in [45, 180] (less does not empty a spoon or a pitcher, more turns it back)."""
    if roll_deg is None:
        return None
    r = float(roll_deg)
    if not (np.isfinite(r) and 45.0 <= r <= 180.0):
        raise ValueError(f"the demonstrator's roll must be within [45, 180] degrees, got {roll_deg!r}")
    return r


def _dump_roll(task: str, rng, roll_deg: float | None = None) -> float:
    """A demonstration's dumping / pouring roll (rad): uniform within ``ROLL_SPREAD`` of the
    nominal ``roll_deg`` (None: the task's, ``DUMP_NOMINAL``)."""
    spread = ROLL_SPREAD[task]
    nominal = DUMP_NOMINAL[task][1] if roll_deg is None else float(roll_deg)
    return float(np.deg2rad(nominal + rng.uniform(-spread, spread)))


def dump_pose(task: str, bowl_xy, dyaw: float = 0.0, tool_point=None) -> np.ndarray:
    """``T_world_tool (4, 4)`` of the demonstrator's nominal dump (powder) or pour over the bowl
    at ``bowl_xy``, facing ``dyaw`` rad off its usual bearing: the task point's position and the
    gripper's orientation (the tool frame of the module docstring)."""
    if task not in DUMP_NOMINAL:
        raise ValueError(f"task must be 'powder' or 'pour', got {task!r}")
    above, roll_deg = DUMP_NOMINAL[task]
    tool_point = TASK_POINTS[task] if tool_point is None else tool_point
    yaw, roll = facing(bowl_xy) + dyaw, np.deg2rad(roll_deg)
    T = np.eye(4)
    T[:3, :3] = tool_rotation(yaw, 0.0, roll)[0]
    T[:3, 3] = (bowl_xy[0], bowl_xy[1], L.TABLE_TOP_Z + L.BOWL_HEIGHT + above)
    if task == "pour":
        T[:2, 3] += _pour_aim(yaw, 0.0, roll, tool_point)
    return T


def _keyframes(task: str, bowl_xy, start: np.ndarray, rng, tool_point,
               roll_deg: float | None = None) -> tuple[np.ndarray, list]:
    """Keyframes (K, 6) and per-segment (nominal duration, pause after the keyframe) lists;
    ``roll_deg``: the demonstrator's nominal roll (None: the task's)."""
    bx, by = bowl_xy
    top = L.TABLE_TOP_Z
    yaw = facing(bowl_xy) + np.deg2rad(rng.uniform(-10, 10))  # facing differs by some degrees
    tilt = np.deg2rad(rng.uniform(-8, 8))                      # and so does the tilt
    x0, y0, _z0, yaw0 = start
    back = np.r_[SHOULDER_XY[0] - x0, SHOULDER_XY[1] - y0, 0.0]
    back /= np.linalg.norm(back)  # lifting out of the source, slightly outwards
    lift = start[:3] - back * rng.uniform(0.0, 0.04) + [rng.normal(0, 0.01), rng.normal(0, 0.01),
                                                         rng.uniform(0.02, 0.04)]
    clear = 0.08 if task == "pour" else 0.0  # the pitcher's cup hangs 0.1 m below its task point
    above = np.array([bx, by, top + clear + rng.uniform(0.17, 0.21)]) + np.r_[rng.normal(0, 0.02, 2), 0]
    mid = 0.5 * (lift + above) + [0, 0, rng.uniform(-0.01, 0.02)]
    side = np.array([-(above - lift)[1], (above - lift)[0], 0.0])
    mid += side / max(np.linalg.norm(side), 1e-9) * rng.normal(0, 0.03)  # approach deviates a few cm
    if task == "powder":
        work = np.array([bx, by, top + L.BOWL_HEIGHT + rng.uniform(0.04, 0.07)]) + np.r_[rng.normal(0, 0.012, 2), 0]
        turned = dict(roll=_dump_roll(task, rng, roll_deg), pitch=tilt)
        # a person flips the spoon over briskly and holds it there while the powder falls
        hold, turn_t = rng.uniform(1.0, 1.8), 1.3
    else:
        # the cup hangs beside and 0.1 m below the spout: the task point well above the rim
        work = np.array([bx, by, top + L.BOWL_HEIGHT + rng.uniform(0.12, 0.15)]) + np.r_[rng.normal(0, 0.01, 2), 0]
        # the spout (-x) turned down, well past 90 deg: a person pours until the pitcher is empty
        turned = dict(roll=_dump_roll(task, rng, roll_deg), pitch=tilt)
        work[:2] += _pour_aim(yaw, turned["pitch"], turned["roll"], tool_point)
        hold, turn_t = rng.uniform(1.2, 2.0), 2.4
    end = start[:3] + np.r_[rng.normal(0, 0.03, 2), rng.uniform(0.0, 0.05)]
    yaw_mid = 0.5 * (yaw0 + yaw)
    rows = [  # (x, y, z, yaw, pitch, roll), (nominal seconds of the segment into it, pause at it)
        (start[:3], yaw0, 0.0, 0.0, 0.0, rng.uniform(0.0, 0.3)),
        (lift, yaw0, 0.0, 0.0, 1.0, 0.0),
        (mid, yaw_mid, 0.5 * tilt, 0.0, 1.4, 0.0),
        (above, yaw, tilt, 0.0, 1.8, rng.uniform(0.0, 0.4)),
        (work, yaw, tilt, 0.0, 1.0, rng.uniform(0.0, 0.3)),
        (work, yaw, turned["pitch"], turned["roll"], turn_t, hold),
        (work + [0, 0, 0.01], yaw, tilt, 0.0, turn_t, 0.0),
        (above + [0, 0, 0.02], yaw, tilt, 0.0, 1.0, 0.0),
        (end, yaw0, 0.0, 0.0, 2.4, rng.uniform(0.0, 0.3)),
    ]
    kf = np.array([[*r[0], r[1], r[2], r[3]] for r in rows], dtype=float)  # (K, 6)
    timing = [(r[4], r[5]) for r in rows]
    return kf, timing


def draw_path(task: str, bowl_xy, start: np.ndarray, dt: float, rng: np.random.Generator,
              duration_scale: float | None = None, tool_point=None, roll_deg: float | None = None) -> DemoPath:
    """A random human-like demonstration path.

    Parameters
    ----------
    task : "powder" or "pour".
    bowl_xy : (2,) bowl position on the table.
    start : (4,) the task point's start position (x, y, z) and the start yaw.
    dt : sampling interval, s.
    rng : randomness.
    duration_scale : total duration factor (default uniform in [0.7, 1.3], i.e. +-30 %).
    tool_point : (3,) the followed task point in the gripper frame (default ``TASK_POINTS[task]``);
        pouring aims the pitcher's stream, so the pour path depends on where this point is.
    roll_deg : the demonstrator's nominal roll while dumping or pouring, degrees (each
        demonstration within ``ROLL_SPREAD`` of it; default the task's ``DUMP_NOMINAL``: a person
        who tilts less, e.g. 105 for the pour, is another demonstrator).
    """
    if task not in TASK_POINTS:
        raise ValueError(f"task must be 'powder' or 'pour', got {task!r}")
    tool_point = TASK_POINTS[task] if tool_point is None else tool_point
    kf, timing = _keyframes(task, np.asarray(bowl_xy, dtype=float), np.asarray(start, dtype=float), rng,
                            np.asarray(tool_point, dtype=float), check_roll(roll_deg))
    scale = rng.uniform(0.7, 1.3) if duration_scale is None else float(duration_scale)
    # time knots: non-uniform speed (each segment's duration varies on its own) and pauses
    t_knots, u_knots, t = [0.0], [0.0], 0.0
    if timing[0][1] > 0:
        t += timing[0][1] * scale
        t_knots.append(t), u_knots.append(0.0)
    for k in range(1, len(kf)):
        t += timing[k][0] * scale * float(np.exp(np.clip(rng.normal(0.0, 0.25), -0.35, 0.35)))
        t_knots.append(t), u_knots.append(float(k))
        if timing[k][1] > 0:
            t += timing[k][1] * scale
            t_knots.append(t), u_knots.append(float(k))
    u_of_t = PchipInterpolator(np.array(t_knots), np.array(u_knots))
    n = int(np.floor(t / dt)) + 1
    ts = np.arange(n) * dt
    u = np.clip(u_of_t(ts), 0, len(kf) - 1)
    params = PchipInterpolator(np.arange(len(kf), dtype=float), kf, axis=0)(u)  # (S, 6)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = tool_rotation(params[:, 3], params[:, 4], params[:, 5])
    T[:, :3, 3] = params[:, :3]
    return DemoPath(t=ts, T_world_tool=T, u=u, keyframes=kf, bowl_xy=np.asarray(bowl_xy, dtype=float))


def bowl_frame_path(p_world: np.ndarray, bowl_xy) -> np.ndarray:
    """``(S, 3)`` world positions -> positions relative to the bowl's base frame (world-aligned)."""
    return np.asarray(p_world) - np.array([bowl_xy[0], bowl_xy[1], L.TABLE_TOP_Z])
