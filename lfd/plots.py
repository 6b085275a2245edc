"""Pictures people would rather look at than read (matplotlib is imported inside each function)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

__all__ = ["plot_import", "plot_plan_features"]


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


def plot_import(demoset, report: list[dict], path: str | Path, max_demos: int = 12) -> Path:
    """What ``lfd-import`` did to each demonstration, one row each (the first ``max_demos``).

    Left: the gripper's position (base frame, from the joints by forward kinematics) over the
    recording's time; right: each tracked landmark's distance from where it was first read.
    Shaded: the pauses trimmed; ticks along the bottom: the missing readings bridged (black for
    the joints, a landmark's colour for its dropouts); red dashed lines: outliers dropped.
    ``report``: ``lfd.io.recordings.import_raw``'s, in the set's order.
    """
    from matplotlib.figure import Figure

    from lfd.robot.kinematics import KinematicModel

    kin = KinematicModel.from_spec(demoset.robot)
    n = min(len(demoset.demos), max_demos)
    fig = Figure(figsize=(11, 1.9 * n + 0.8))
    axes = np.atleast_2d(fig.subplots(n, 2, sharex="row", squeeze=False))
    colours = {name: f"C{3 + k}" for k, name in enumerate(demoset.landmark_names)}
    for row, (demo, rep) in enumerate(zip(demoset.demos[:n], report[:n])):
        t = rep["start_s"] + np.arange(demo.n_samples) * demo.dt  # (S,) the recording's time
        with torch.no_grad():
            p = kin.fk(torch.as_tensor(demo.q, dtype=kin.dtype))[:, :3, 3].cpu().numpy()  # (S, 3)
        left, right = axes[row]
        for k, axis in enumerate("xyz"):
            left.plot(t, p[:, k], lw=1.2, label=f"gripper {axis}")
        lm = np.asarray(demo.landmarks)
        if lm.ndim == 4:
            for z, name in enumerate(demoset.landmark_names):
                if rep["tracks"][name]["rate_hz"] is not None:
                    d = np.linalg.norm(lm[:, z, :3, 3] - lm[0, z, :3, 3], axis=1)
                    right.plot(t, d, lw=1.2, color=colours[name], label=name)
        for ax in (left, right):
            if rep["trimmed_start_s"]:
                ax.axvspan(0.0, rep["start_s"], color="0.85", lw=0)
            if rep["trimmed_end_s"]:
                ax.axvspan(rep["end_s"] - rep["trimmed_end_s"], rep["end_s"], color="0.85", lw=0)
        if rep["joints"]["dropout_times"]:
            left.plot(rep["joints"]["dropout_times"], np.zeros(len(rep["joints"]["dropout_times"])), "|",
                      color="k", ms=8, transform=left.get_xaxis_transform())
        for name, tr in rep["tracks"].items():
            if tr["dropout_times"]:
                right.plot(tr["dropout_times"], np.zeros(len(tr["dropout_times"])), "|", color=colours[name], ms=8,
                           transform=right.get_xaxis_transform())
            for x in tr["outlier_times"]:
                right.axvline(x, color="red", ls="--", lw=0.9)
        bits = [f"{sum(tr['dropouts'] for tr in rep['tracks'].values()) + rep['joints']['dropouts']} dropouts",
                f"{sum(tr['outliers'] for tr in rep['tracks'].values())} outliers"]
        left.set_title(f"{rep['name']}: gripper (m)", fontsize=9, loc="left")
        right.set_title(f"landmarks: distance from their first reading (m); {', '.join(bits)}", fontsize=9, loc="left")
        if row == 0:
            left.legend(loc="upper right", fontsize=7, ncol=3)
            if right.lines:
                right.legend(loc="upper right", fontsize=7, ncol=2)
    for ax in axes[-1]:
        ax.set_xlabel("time in the recording (s)", fontsize=8)
    shown = f"the first {n} of {len(demoset.demos)} demonstrations; " if len(demoset.demos) > n else ""
    fig.suptitle(f"{shown}shaded: pauses trimmed; ticks at the bottom: missing readings bridged; "
                 "red dashed: outliers dropped", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=90)
    return path
