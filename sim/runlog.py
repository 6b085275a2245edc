"""The log of an evaluation's runs, ``runs.jsonl``: what identifies a logged run (its settings),
which logged runs count for an evaluation (``--resume``), and where each run's task-point path is
saved. ``sim.evaluate`` appends a line per finished run; a line cut by a kill is skipped, a
hand-edited one that cannot be counted is named.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from lfd.cli import UsageError
from sim.runner import EXEC_PACE

__all__ = ["read_log", "run_settings_of", "save_path"]


def save_path(out_dir: Path, row: dict, path) -> str:
    """Write a run's task-point path ``(P, 3)`` (world frame, m, one point every
    ``ExecSettings.record_every`` simulation steps) to ``paths/<variant>[_demos<k>]_<latency>_<scenario>.npy``
    under ``out_dir``, or ``..._<scenario>_<k>.npy`` with the first ``k >= 2`` free when that file
    exists; returns that name relative to ``out_dir`` (what ``runs.jsonl`` records). A log may keep
    runs of another setting (roadmap size, models, latency...), which are run again beside them
    (``evaluate``): each row keeps its own path (the second run's path had overwritten the first's,
    which its row still named)."""
    draw = f"_demos{row['demo_seed']}" if row.get("demo_seed") else ""
    stem = f"{row['variant']}{draw}_{row.get('latency', 'none')}_{row['scenario']}"
    (out_dir / "paths").mkdir(parents=True, exist_ok=True)
    rel, k = Path("paths") / f"{stem}.npy", 1
    while (out_dir / rel).exists():
        k += 1
        rel = Path("paths") / f"{stem}_{k}.npy"
    np.save(out_dir / rel, np.asarray(path, dtype=np.float64).reshape(-1, 3))
    return rel.as_posix()


def _is_int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


# what the results read of a finished run (sim.report), by the check its value must pass
_FINISHED_FIELDS = {"success": lambda x: isinstance(x, bool), "reason": lambda x: isinstance(x, str),
                    "fraction_in_bowl": _is_number, "initial_ms": _is_number, "contacts": lambda x: isinstance(x, list),
                    "replan_ms": lambda x: isinstance(x, list) and all(map(_is_number, x))}


def _row_problem(r: dict) -> str | None:
    """Why a logged run cannot be counted (a hand-edited or foreign ``runs.jsonl``), or None."""
    if not (isinstance(r.get("variant"), str) and _is_int(r.get("scenario")) and _is_int(r.get("demo_seed", 0))):
        return "a logged run needs a variant name and whole-number scenario and demo_seed"
    if "error" in r:
        return None
    bad = [k for k, ok in _FINISHED_FIELDS.items() if k not in r or not ok(r[k])]
    return f"a finished run with missing or malformed {', '.join(bad)}" if bad else None


# settings of a run that only the CPU's load depends on: they decide a run's identity when its
# latency is measured (the world moves on for the planner's wall-clock time, which the other
# processes on the machine lengthen); runs logged before they were recorded count
_LOAD_SETTINGS = ("executor", "workers")


def run_settings_of(settings, models: Path) -> dict:
    """``settings``: a ``sim.evaluate.EvalSettings``. What makes two logged runs of one (variant, draw, scenario) the same run, besides the
    latency mode and the executor's pace: the task, the roadmap size, the models folder, the bowl
    move when set, and with measured latency the executor and its workers (or cluster address)."""
    out: dict = {"task": settings.task, "roadmap_size": settings.roadmap_size, "models": str(models)}
    if settings.move_bowl:  # (only then: runs logged before the option existed still count)
        out["move_bowl"] = True
    if settings.latency == "measured":
        out["executor"] = settings.executor
        out["workers"] = settings.address or settings.workers
    return out


def _same_settings(logged: dict, wanted: dict) -> bool:
    """Whether a run logged with ``logged`` settings counts for ``wanted`` ones (a load setting
    the row does not record counts as the same)."""
    keys = set(logged) | set(wanted)
    return all(_same_value(k, logged.get(k), wanted.get(k)) for k in keys
               if not (k in _LOAD_SETTINGS and k not in logged))


def _same_value(key: str, logged, wanted) -> bool:
    """One setting; the models folder by where it is from here (``mdir``, ``./mdir`` and its
    absolute path are one folder; logged as given, so a project moved with its runs still counts
    them when named relatively)."""
    if key == "models" and isinstance(logged, str) and isinstance(wanted, str):
        return os.path.realpath(logged) == os.path.realpath(wanted)
    return logged == wanted


def read_log(log: Path, latency: str, run_settings: dict) -> tuple[dict, dict, int, int, bool]:
    """The runs logged in ``log`` that count for an evaluation in latency mode ``latency`` with
    ``run_settings`` (``run_settings_of``; rows logged before they were recorded count):
    ``(done, crashed, lines, other, cut)``, the first two keyed by ``(variant, demo_seed, scenario)``:
    finished runs, runs that failed twice (run again), how many readable lines the log holds, how
    many of them were made with other settings (run again), and whether its last line was cut (by
    a kill while it was written)."""
    done: dict = {}
    crashed: dict = {}
    lines = other = 0
    try:
        text = log.read_text() if log.is_file() else ""
    except UnicodeDecodeError as e:
        raise UsageError(f"{log}: not a log of runs (not UTF-8 text: {e})") from e
    for n, line in enumerate(text.splitlines(), 1):
        try:
            r = json.loads(line)
        except (ValueError, RecursionError):
            continue  # a line cut by an interruption
        if not isinstance(r, dict):
            raise UsageError(f"{log}, line {n}: a logged run is a JSON object, got {type(r).__name__}")
        if not isinstance(r.get("settings", {}), dict):
            raise UsageError(f"{log}, line {n}: a logged run's settings are a JSON object, "
                             f"got {type(r['settings']).__name__}")
        lines += 1
        # runs of another setting are redone: logged without a latency mode, a run was made in a
        # frozen world ("none"); with a dwell other than the paper's interval (an option since
        # removed), with other edge costs; paced otherwise
        if r.get("latency", "none") != latency or r.get("dwell", "interval") != "interval" \
                or r.get("pace") != EXEC_PACE or not _same_settings(r.get("settings", run_settings), run_settings):
            other += 1
            continue
        why = _row_problem(r)
        if why:
            raise UsageError(f"{log}, line {n}: {why}; correct or delete that line, or choose another --out")
        key = (r["variant"], r.get("demo_seed", 0), r["scenario"])
        if "error" in r:
            if key not in done:
                crashed[key] = r
        else:
            done[key] = r
            crashed.pop(key, None)
    cut = bool(text) and not text.endswith("\n")  # the last line was cut by a kill
    return done, crashed, lines, other, cut
