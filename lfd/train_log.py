"""The training command's log: progress lines on stdout and TensorBoard scalars and images.

``lfd.train_cli`` (``lfd-train`` / ``train.py``) owns the one ``SummaryWriter`` through ``Logger``;
the library (``lfd.learning``) reports through callbacks and writes no logs.
"""

from __future__ import annotations

import shutil
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["Logger"]


class Logger:
    """Progress on stdout and TensorBoard scalars/images (the only SummaryWriter owner).

    Each session of a fit logs into a run of its own, ``out/tensorboard/session-<k>``, made at its
    first event (a run refused before learning leaves none): a ``resume``d session's restarts
    start their curves again from step 0 beside the earlier session's, and a fresh fit first
    removes the earlier fits' runs, which described the model it replaces (they were mixed into
    one curve). ``quiet``: no line per EM iteration. Without TensorBoard installed it says so
    once on stderr and writes no logs."""

    def __init__(self, out: Path, joint_names, quiet: bool = False, prog: str = "lfd-train", resume: bool = False):
        self.root = Path(out) / "tensorboard"
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError as e:
            self._make = None
            print(f"{prog}: warning: TensorBoard is not installed ({e}), so no TensorBoard logs are written "
                  f"to {self.root}; pip install tensorboard to have them", file=sys.stderr, flush=True)
        else:
            self._make = SummaryWriter
        self.resume = resume
        self._writer = None
        self.joint_names = list(joint_names)
        self.quiet = quiet
        self.step = 0
        self.t0 = time.perf_counter()

    @property
    def writer(self):
        """The session's ``SummaryWriter`` (None without TensorBoard), made on first use."""
        if self._writer is None and self._make is not None:
            if not self.resume:
                for old in self.root.glob("session-*"):
                    shutil.rmtree(old, ignore_errors=True)
                for old in self.root.glob("events.out.tfevents.*"):  # (written there before sessions)
                    old.unlink(missing_ok=True)
            k = 0
            while (self.root / f"session-{k}").exists():
                k += 1
            self._writer = self._make(str(self.root / f"session-{k}"))
        return self._writer

    def __call__(self, ev: dict) -> None:
        self.step += 1
        tag = f"{ev['stage']}{ev['restart']}"
        if not self.quiet:
            print(f"[{time.perf_counter() - self.t0:6.1f}s] {ev['stage']} {ev['restart']} iter {ev['iteration'] + 1}: "
                  f"loss {ev['loss']:.4f}  tool {np.round(ev['tool'], 3).tolist()}", flush=True)
        w = self.writer
        if w is None:
            return
        w.add_scalar(f"loss/{tag}", ev["loss"], ev["iteration"])
        w.add_scalar("loss/all", ev["loss"], self.step)
        for name, x in zip(ev["landmarks"], ev["env"]):
            w.add_scalar(f"landmarks/{name}", float(x), self.step)
        for axis, x in zip("xyz", ev["tool"]):
            w.add_scalar(f"tool/{axis}", float(x), self.step)

    def final(self, result) -> None:
        w = self.writer
        if w is None:
            return
        m = result.model
        std = np.sqrt(np.diagonal(m.covariances.cpu().numpy(), axis1=1, axis2=2))  # (T, F)
        names = self.joint_names + ["task_x", "task_y", "task_z"]
        names += [f"gripper_{axis}_{c}" for axis in "xy" for c in "xyz"][:m.n_task_features - 3]  # the attitude's
        for t in range(m.time_steps):
            for j, n in enumerate(names):
                w.add_scalar(f"features/std/{n}", float(std[t, j]), t)
            w.add_scalar("alignment/effective_demos", result.effective_demos[t], t)
        for i, a in enumerate(result.alignments):
            img = np.zeros((1, m.time_steps, len(a)), dtype=np.float32)  # (C, H = step, W = sample)
            img[0, a, np.arange(len(a))] = 1.0
            w.add_image(f"alignment/demo_{i:02d}", img, 0)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        self._make = None  # (no writer is made after the close)
