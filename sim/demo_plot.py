"""A picture of a demonstration set: the task point's path relative to the bowl (side and top
views, and its distance to the bowl over time), as in ``docs/demos.png``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from lfd.robot.kinematics import KinematicModel
from lfd.robot.robots import BAXTER_LEFT
from sim import layout as L
from sim.demo_paths import bowl_frame_path

__all__ = ["plot_demos"]


def plot_demos(attempts, tool_point, out_png, title: str = "") -> Path:
    """Draw the task point's path relative to the bowl for ``attempts`` (side and top views)."""
    from matplotlib.figure import Figure  # no pyplot: the caller's backend and figures stay as they are
    from matplotlib.patches import Circle, Rectangle

    kin = KinematicModel.from_spec(BAXTER_LEFT, dtype=torch.float64)
    fig = Figure(figsize=(15, 4.5))
    axes = fig.subplots(1, 3)
    for k, a in enumerate(attempts):
        T = kin.fk(torch.as_tensor(a.q)).numpy()
        pw = T[:, :3, 3] + np.einsum("sij,j->si", T[:, :3, :3], np.asarray(tool_point))
        rel = bowl_frame_path(pw, a.path.bowl_xy)
        t = np.arange(len(a.q)) * (a.path.t[1] - a.path.t[0])
        axes[0].plot(rel[:, 0], rel[:, 2], lw=1, label=f"demo {k}")
        axes[1].plot(rel[:, 0], rel[:, 1], lw=1)
        axes[2].plot(t, np.linalg.norm(rel[:, :2], axis=1), lw=1)
    for ax, (xl, yl) in zip(axes, [("x - bowl (m)", "z - bowl bottom (m)"), ("x - bowl (m)", "y - bowl (m)"),
                                   ("time (s)", "horizontal distance to bowl (m)")]):
        ax.set_xlabel(xl), ax.set_ylabel(yl), ax.grid(alpha=0.3)
    axes[0].add_patch(Rectangle((-L.BOWL_RADIUS, 0), 2 * L.BOWL_RADIUS, L.BOWL_HEIGHT, color="g", alpha=0.3))
    axes[1].add_patch(Circle((0, 0), L.BOWL_RADIUS, color="g", alpha=0.3))
    axes[0].set_aspect("equal"), axes[1].set_aspect("equal")
    axes[0].legend(fontsize=7)
    fig.suptitle(title or "task point relative to the bowl")
    fig.tight_layout()
    out_png = Path(out_png)
    fig.savefig(out_png, dpi=90)
    return out_png
