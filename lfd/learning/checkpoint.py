"""A fit that survives interruption: atomic files, restart checkpoints, and SIGINT/SIGTERM.

Files are written atomically (``atomic_write_bytes``): a temporary file in the same folder,
``fsync``, ``os.replace`` over the target, ``fsync`` of the folder. A reader sees the old file
or the new one, never half of one, and an interrupted write leaves no temporary file behind.

Checkpoint format (in the training output folder)::

    checkpoint.json      the commit record: format, config, demonstrations' fingerprint, per-restart
                         losses, histories and notes, best restart, and the name + sha256 of ...
    checkpoint_rNNN.pt   tensors only (``torch.load(weights_only=True)``): the best restart's
                         ``tool, env, mu, sigma_inv, log_trans`` and its ``alignment`` (N,)

A save writes the new ``.pt`` first, then replaces ``checkpoint.json`` (the commit), then
removes older ``.pt`` files, so the record always names a complete tensor file.

``InterruptGuard`` turns SIGINT and SIGTERM into ``Interrupted`` (a ``KeyboardInterrupt``
carrying the signal) in the main thread; inside ``guard.critical()`` a signal is held back
until the block ends, so a checkpoint or a model is never cut in half by Ctrl-C.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import math
import os
import pickle
import re
import signal
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from lfd.errors import UserInputError

__all__ = [
    "STATE_TENSORS",
    "CheckpointError",
    "FitProgress",
    "InterruptGuard",
    "Interrupted",
    "atomic_torch_save",
    "atomic_write_bytes",
    "atomic_write_text",
    "checkpoint_path",
    "config_record",
    "demos_fingerprint",
    "load_checkpoint",
    "remove_checkpoint",
    "save_checkpoint",
    "temp_files",
]

FORMAT = "lfd-fit-checkpoint/1"
RECORD = "checkpoint.json"
TMP_MARK = ".tmp-"
STATE_TENSORS = ("tool", "env", "mu", "sigma_inv", "log_trans", "alignment")


class CheckpointError(UserInputError):
    """A checkpoint that is missing, damaged, or made for other demonstrations or options (a
    ``ValueError``; the commands report it as one line)."""


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM arrived; ``exit_status`` is the shell's ``128 + signum``."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)
        self.name = signal.Signals(signum).name
        self.exit_status = 128 + self.signum


# ----------------------------------------------------------------------------- atomic files
def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Replace ``path`` by ``data`` atomically (temp file in the same folder, fsync, os.replace)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}{TMP_MARK}{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    try:  # make the rename itself durable
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError:
        pass
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))


def refused_load_cause(e: Exception) -> str:
    """What ``torch.load(weights_only=True)`` refused (its ``UnpicklingError`` ``e``), without
    torch's advice to load with ``weights_only=False`` (which would run the file's code, and
    would not mend a damaged file)."""
    m = re.search(r"WeightsUnpickler error:\s*(.*?)\s*(?:Check the documentation|\Z)", str(e), re.DOTALL)
    cause = " ".join(m.group(1).split()).split(". ")[0] if m else str(e).strip().splitlines()[0]
    if cause.startswith("Unsupported global"):
        return f"it holds Python objects, not only tensors ({cause})"
    return f"damaged, or not a file torch.save wrote ({cause})"


def atomic_torch_save(obj, path: str | Path) -> Path:
    """``torch.save`` to memory, then ``atomic_write_bytes``."""
    buf = io.BytesIO()
    torch.save(obj, buf)
    return atomic_write_bytes(path, buf.getvalue())


def temp_files(folder: str | Path) -> list[Path]:
    """Temporary files an atomic write left in ``folder`` (none unless a process was killed)."""
    return sorted(p for p in Path(folder).iterdir() if TMP_MARK in p.name)


# ----------------------------------------------------------------------------- what a checkpoint is
def config_record(cfg) -> dict:
    """The fields of a ``FitConfig`` that change a fit, as JSON values (callables by name)."""
    out = {}
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            v = dataclasses.asdict(v)  # FitConfig.solver
        elif callable(v):
            v = getattr(v, "__qualname__", type(v).__name__)
        elif isinstance(v, tuple):
            v = list(v)
        out[f.name] = v
    return out


def demos_fingerprint(demoset, settings: bool = True) -> str:
    """sha256 of what a fit reads from a ``DemoSet``: names, every array and, with ``settings``,
    the robot and the task. The task's ``subsample`` is left out: it only picks a default of
    ``FitConfig.subsample``, which ``config_record`` covers, so editing it in ``task.json`` reads as
    an option change. Without ``settings``, the recordings alone: what an evaluation checks a
    trained model against (an edited ``task.json`` does not make them other demonstrations)."""
    h = hashlib.sha256()
    head: dict = {"joints": list(demoset.joint_names), "landmarks": list(demoset.landmark_names),
                  "demos": [[d.name, list(d.q.shape), float(d.dt)] for d in demoset.demos]}
    if settings:
        task = {k: v for k, v in demoset.task.to_dict().items() if k != "subsample"} if demoset.task else None
        head.update(robot=demoset.robot.to_dict(), task=task)
    h.update(json.dumps(head, sort_keys=True).encode())
    for d in demoset.demos:
        h.update(np.ascontiguousarray(d.q, dtype=np.float64).tobytes())
        h.update(np.ascontiguousarray(d.landmarks, dtype=np.float64).tobytes())
    return h.hexdigest()


@dataclass(frozen=True)
class FitProgress:
    """The restarts of a fit finished so far (``lfd.learning.learn.fit`` reports one after each restart).

    restart_losses : per finished restart, per observation; ``nan`` for a dropped one.
    best_state : tensors ``STATE_TENSORS`` of the best restart (``alignment (N,)`` int64,
        the demonstrations concatenated), or None when every restart so far was dropped.
    """

    config: dict
    fingerprint: str
    restart_losses: tuple[float, ...] = ()
    loss_history: tuple[tuple[float, ...], ...] = ()
    em_iterations: tuple[int, ...] = ()
    notes: tuple[str, ...] = ()
    best_restart: int | None = None
    best_state: dict | None = field(default=None, compare=False)
    source: Path | None = field(default=None, compare=False)
    elapsed_s: float = field(default=0.0, compare=False)  # the fit's wall time to this checkpoint, every session's
    # (what a session spent on a restart an interruption cut is not counted)

    @property
    def restarts_done(self) -> int:
        return len(self.restart_losses)

    def mismatch(self, config: dict, fingerprint: str) -> str | None:
        """Why this progress cannot continue a fit of ``config`` on demonstrations ``fingerprint``."""
        if fingerprint != self.fingerprint:
            return "made from different demonstrations (their contents differ)"
        diff = [k for k in sorted(set(config) | set(self.config)) if config.get(k) != self.config.get(k)]
        if diff:
            return "made with different options: " + ", ".join(
                f"{k}={self.config.get(k)!r} there, {config.get(k)!r} now" for k in diff)
        return None


def checkpoint_path(folder: str | Path) -> Path:
    return Path(folder) / RECORD


def save_checkpoint(folder: str | Path, progress: FitProgress) -> Path:
    """Write ``progress`` into ``folder`` (two files, committed by the record); returns the record."""
    folder = Path(folder)
    n = progress.restarts_done
    pt_name = f"checkpoint_r{n:03d}.pt"
    state = {}
    if progress.best_state is not None:
        state = {k: progress.best_state[k].detach().cpu().clone() for k in STATE_TENSORS}
    buf = io.BytesIO()
    torch.save(state, buf)
    data = buf.getvalue()
    atomic_write_bytes(folder / pt_name, data)
    record = {"format": FORMAT, "restarts_done": n, "state_file": pt_name,
              "state_sha256": hashlib.sha256(data).hexdigest(), "config": progress.config,
              "demos_fingerprint": progress.fingerprint,
              "restart_losses": [None if not np.isfinite(x) else float(x) for x in progress.restart_losses],
              "loss_history": [list(h) for h in progress.loss_history],
              "em_iterations": list(progress.em_iterations), "notes": list(progress.notes),
              "best_restart": progress.best_restart, "elapsed_s": float(progress.elapsed_s)}
    atomic_write_text(folder / RECORD, json.dumps(record, indent=2) + "\n")
    for old in folder.glob("checkpoint_r*.pt"):
        if old.name != pt_name:
            old.unlink(missing_ok=True)
    return folder / RECORD


def _seconds(x) -> float:
    """A recorded duration: a finite number >= 0 (a checkpoint written before durations were
    recorded has none: 0)."""
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) or x < 0:
        raise ValueError(f"elapsed_s must be a number of seconds >= 0, got {x!r}")
    return float(x)


def read_json(path: Path, error: type[Exception]):
    """The JSON value in ``path``; ``error`` (naming the file) when it is not valid JSON (or
    nested too deep to read)."""
    try:
        return json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError, RecursionError) as e:
        raise error(f"{path}: not valid JSON ({e})") from e


def read_json_record(path: Path, fmt: str, error: type[Exception], what: str) -> dict:
    """The JSON object in ``path`` whose ``"format"`` is ``fmt``; ``error`` (naming the file) when
    it is not valid JSON (or nested too deep to read) or not ours."""
    rec = read_json(path, error)
    if not isinstance(rec, dict) or rec.get("format") != fmt:
        raise error(f"{path}: not an lfd {what} (expected format {fmt!r}, got "
                    f"{rec.get('format') if isinstance(rec, dict) else rec!r})")
    return rec


def load_checkpoint(folder: str | Path) -> FitProgress:
    """Read what ``save_checkpoint`` wrote.

    Raises
    ------
    CheckpointError
        no checkpoint in ``folder``, a record that is not ours, or a tensor file that is
        missing, damaged (sha256) or holds something other than the expected tensors.
    """
    folder = Path(folder)
    rec_path = folder / RECORD
    if not rec_path.is_file():
        raise CheckpointError(f"{folder}: no checkpoint to resume from ({RECORD} is missing)")
    rec = read_json_record(rec_path, FORMAT, CheckpointError, "fit checkpoint")
    try:
        pt_path = folder / Path(str(rec["state_file"])).name
        data = pt_path.read_bytes()
    except KeyError as e:
        raise CheckpointError(f"{rec_path}: incomplete record (no {e})") from e
    except OSError as e:
        raise CheckpointError(f"{rec_path}: its tensor file cannot be read ({e.strerror or e})") from e
    if hashlib.sha256(data).hexdigest() != rec.get("state_sha256"):
        raise CheckpointError(f"{pt_path}: damaged (sha256 differs from {RECORD}'s)")
    try:
        state = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        raise CheckpointError(f"{pt_path}: cannot be read as tensors: {refused_load_cause(e)}") from e
    except Exception as e:  # torch raises several kinds for foreign files
        raise CheckpointError(f"{pt_path}: cannot be read as tensors ({e})") from e
    if not isinstance(state, dict) or (state and set(state) != set(STATE_TENSORS)) \
            or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise CheckpointError(f"{pt_path}: expected tensors {list(STATE_TENSORS)}")
    try:
        losses = tuple(float("nan") if x is None else float(x) for x in rec["restart_losses"])
        progress = FitProgress(
            config=dict(rec["config"]), fingerprint=str(rec["demos_fingerprint"]), restart_losses=losses,
            loss_history=tuple(tuple(float(x) for x in h) for h in rec["loss_history"]),
            em_iterations=tuple(int(x) for x in rec["em_iterations"]), notes=tuple(map(str, rec["notes"])),
            best_restart=None if rec["best_restart"] is None else int(rec["best_restart"]),
            best_state=state or None, source=rec_path, elapsed_s=_seconds(rec.get("elapsed_s", 0.0)))
    except (KeyError, TypeError, ValueError) as e:
        raise CheckpointError(f"{rec_path}: incomplete record ({type(e).__name__}: {e})") from e
    if (progress.best_restart is None) != (progress.best_state is None):
        raise CheckpointError(f"{rec_path}: best restart and tensor file disagree")
    n = len(progress.restart_losses)
    if len(progress.loss_history) < n or len(progress.em_iterations) < n:
        raise CheckpointError(f"{rec_path}: incomplete record ({n} restart losses, "
                              f"{len(progress.loss_history)} loss histories, {len(progress.em_iterations)} iteration counts)")
    if progress.best_restart is not None and not 0 <= progress.best_restart < n:
        raise CheckpointError(f"{rec_path}: best restart {progress.best_restart} is not one of its {n} restarts")
    if progress.best_state is not None and not all(  # log_trans holds -inf for an impossible transition
            bool((torch.isfinite(v) | ((v == float("-inf")) & (k == "log_trans"))).all())
            for k, v in progress.best_state.items()):
        raise CheckpointError(f"{pt_path}: holds NaN or infinite values")
    return progress


# ----------------------------------------------------------------------------- signals
class InterruptGuard:
    """``with InterruptGuard() as guard:`` SIGINT/SIGTERM raise ``Interrupted`` in the main thread.

    ``with guard.critical():`` holds a signal back until the block ends (then raises it).
    The previous handlers come back when the guard exits.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self._old, self._depth, self._pending = {}, 0, None

    def __enter__(self):
        for s in self.SIGNALS:
            self._old[s] = signal.signal(s, self._handle)
        return self

    def __exit__(self, *exc):
        for s, h in self._old.items():
            signal.signal(s, h)
        self._old.clear()
        return False

    def _handle(self, signum, frame):
        if self._depth:
            self._pending = self._pending or signum
            return
        raise Interrupted(signum)

    @contextmanager
    def critical(self):
        """A block a signal does not cut: one that arrives inside raises ``Interrupted`` when the
        block ends, unless the block failed: then its own error is the report (a checkpoint that
        could not be written is not "interrupted, checkpoint saved")."""
        self._depth += 1
        finished = False
        try:
            yield
            finished = True
        finally:
            self._depth -= 1
            if self._depth == 0 and self._pending is not None:
                signum, self._pending = self._pending, None
                if finished:
                    raise Interrupted(signum)


def remove_checkpoint(folder: str | Path) -> None:
    """Remove ``folder``'s checkpoint (the record first, so no half of one is ever taken for it)."""
    folder = Path(folder)
    (folder / RECORD).unlink(missing_ok=True)
    for old in folder.glob("checkpoint_r*.pt"):
        old.unlink(missing_ok=True)
