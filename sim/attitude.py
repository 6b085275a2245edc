"""How far the tool is tilted: the attitude the dump and the pour are judged by (issue 24).

The simulated tools are held with gripper y as their "up" (``sim.demo_paths``: ``R_level`` puts
gripper y on world +z; the dump and the pour roll the tool about gripper z). The *tilt* of a
tool pose is the angle between its up axis and world up, 0 deg level, 90 deg on its side, 180
deg upside down: for the small pitches of the demonstrations it is the roll of the dump or
pour. ``demo_tilt`` is the demonstrations' reference: each demonstration's largest tilt (the
held dump or pour), and their mean; an execution's tilt error is its largest tilt minus that mean
(negative: it tilted less than the demonstrator).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

__all__ = ["demo_tilt", "tilts_of", "tool_tilt_deg"]


def tool_tilt_deg(R_world_tool) -> np.ndarray:
    """``(..., 3, 3)`` tool (gripper) orientations -> ``(...)`` tilt in degrees, in [0, 180]."""
    R = np.asarray(R_world_tool, dtype=float)
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"Expected rotations of shape (..., 3, 3), got {R.shape}")
    return np.degrees(np.arccos(np.clip(R[..., 2, 1], -1.0, 1.0)))


def tilts_of(kin, Q) -> tuple[np.ndarray, np.ndarray]:
    """Joint configurations ``Q (S, d)`` -> ``(T_world_ee (S, 4, 4), tilt (S,) deg)`` by ``kin``'s
    forward kinematics (an ``lfd.robot.kinematics.KinematicModel``; the tool frame is its end link)."""
    with torch.no_grad():
        T = kin.fk(torch.as_tensor(np.asarray(Q), dtype=kin.dtype, device=kin.device)).cpu().numpy()
    return T, tool_tilt_deg(T[:, :3, :3])


def demo_tilt(demo_dir: str | Path) -> dict:
    """The demonstrations' tilt: ``{"mean": deg, "per_demo": [deg, ...]}``, each demonstration's
    largest tilt (its held dump or pour) by forward kinematics of its recorded joints, and their
    mean. ``{"mean": nan, "per_demo": []}`` when ``demo_dir`` holds no demonstrations."""
    from lfd.learning.demos import demo_files, load_demos
    from lfd.robot.kinematics import KinematicModel

    if not demo_files(demo_dir):
        return {"mean": math.nan, "per_demo": []}
    ds = load_demos(demo_dir)
    kin = KinematicModel.from_spec(ds.robot, dtype=torch.float64)
    per_demo = [float(tilts_of(kin, d.q)[1].max()) for d in ds.demos]
    return {"mean": float(np.mean(per_demo)), "per_demo": per_demo}
