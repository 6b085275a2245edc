"""Pictures people would rather look at than read (matplotlib is imported inside each function)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

__all__ = ["plot_plan_features"]


def plot_plan_features(model, configurations: np.ndarray, time_steps: np.ndarray, landmarks,
                       path: str | Path) -> Path:
    """The plan's task-point path in the virtual-landmark frame against the learned per-step means.

    ``configurations: (n, d)``, ``time_steps: (n,)``, ``landmarks: (Z, 4, 4)`` (kept, model order).
    One panel per task-space axis: the learned mean ±2 standard deviations per time step, and
    the plan's waypoints at their time steps.
    """
    from matplotlib.figure import Figure  # no pyplot: the caller's backend and figures stay as they are

    task = model.tool_features
    with torch.no_grad():
        f = model.features(torch.as_tensor(configurations, dtype=model.dtype), landmarks=landmarks)
        f = f.cpu().numpy()[:, task]
        mu = model.mu.cpu().numpy()[:, task]
        std = torch.sqrt(torch.diagonal(model.covariances, dim1=-2, dim2=-1)).cpu().numpy()[:, task]
    t = np.arange(len(mu))
    fig = Figure(figsize=(7, 7))
    axes = fig.subplots(3, 1, sharex=True)
    for k, (ax, name) in enumerate(zip(axes, "xyz")):
        ax.fill_between(t, mu[:, k] - 2 * std[:, k], mu[:, k] + 2 * std[:, k], alpha=0.25,
                        label="learned mean ± 2σ")
        ax.plot(t, mu[:, k], "-", lw=1.5)
        ax.plot(np.asarray(time_steps), f[:, k], "o-", ms=3,
                lw=0.8, label="plan")
        ax.set_ylabel(f"tool point {name} (m)\nin virtual landmark")
    axes[0].legend(loc="best", fontsize=8)
    axes[-1].set_xlabel("time step")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path
