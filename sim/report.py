"""What an evaluation reports: per-variant summaries of logged runs, their spread over a sweep's
cells, and the paper's table beside the paper's own figures (Tables I and II).

A *cell* of a sweep is one scenario set (base seed) with the models of one demonstration draw
(demonstration seed); ``summarize`` makes a variant's line from the runs of one cell or of all,
``spread`` the mean and standard deviation of the success rates over the cells.
"""

from __future__ import annotations

import math

import numpy as np

from sim.latency import describe_latency, parse_latency

__all__ = ["PAPER_LATENCY_MS", "PAPER_SUCCESS", "format_table", "measured", "spread", "stats", "strict_json", "summarize"]

PAPER_LATENCY_MS = {"powder": 182, "pour": 200}  # the paper's planning latency (Tables I, II; 12 cores)
PAPER_SUCCESS = {  # the paper's success rates (Table I: powder, 10 scenarios; Table II: pour)
    "powder": {"learned+learned": 1.0, "learned+manual": 1.0, "manual+manual": 0.8, "arbitrary+manual": 0.6,
               "no-obstacle-avoidance": 0.1},
    "pour": {"learned+learned": 0.9, "arbitrary+manual": 0.4, "no-obstacle-avoidance": 0.3},
}


def _pct(values, q) -> float:
    return float(np.percentile(values, q)) if len(values) else math.nan


def measured(values) -> np.ndarray:
    """``values`` without the missing ones (None or NaN), as floats."""
    v = np.asarray([x for x in values if x is not None], dtype=float)
    return v[~np.isnan(v)]


def stats(values) -> dict:
    """``{median, p95, mean}`` of the ``measured`` ``values`` (all NaN when none is): the paper's
    latencies are means over 10 scenarios."""
    v = measured(values)
    return {"median": _pct(v, 50), "p95": _pct(v, 95), "mean": float(np.mean(v)) if len(v) else math.nan}


def summarize(runs: list[dict], variant, learning_time_s: float, crashed: int = 0) -> dict:
    """One variant's line of ``results.json`` (``variant``: a ``sim.evaluate.Variant``) from its
    finished runs; ``crashed``: its runs that raised twice. A crashed run is a scene the robot did
    not do: it counts as a failure in ``success_rate`` and in ``n_scenarios`` (finished runs plus
    crashed ones), and is left out of every other figure (it has none).

    Latencies, each ``{median, p95, mean}`` in ms: ``initial_ms`` and ``replan_ms`` are the searches
    alone (the paper's planning latency), of the first plan and of each re-plan after a sensed move
    (``replan_kind`` "move"; the anytime re-plans on a growing roadmap are ``improve_ms``, which they
    had raised the pour's median five-fold in ``replan_ms``); ``build_ms`` is the first landmark update (the
    roadmap's construction) before the first plan, ``improve_ms`` the anytime re-plans after a
    far move (the roadmap's growth, the old plan's check and the search on it), and
    ``reaction_ms`` a re-plan's landmark update (new step costs, new biased vertices after a far
    move), the old plan's check (``sim.execute``) and its search: the time from sensing a move
    to holding the new plan. Runs logged before the update was timed
    have no ``build_ms``/``replan_update_ms`` and are left out of those two. A plan that was not
    found (no path, unreachable: an answer, often at once) is no planning latency and is left out
    of them all."""
    init = [r["initial_ms"] for r in runs if _found(r)[0]]
    rep = [x for r in runs for x, kind, ok in zip(r["replan_ms"], _kinds(r), _found(r)[1:]) if ok and kind == "move"]
    build = [r.get("build_ms") for r in runs]  # (stats leaves out the runs without one)
    react, improve = [], []
    for r in runs:
        if len(r.get("replan_update_ms", ())) != len(r["replan_ms"]):
            continue  # logged before the update was timed
        checks = r.get("path_check_ms") or [0.0] * len(r["replan_ms"])  # (runs logged before the check)
        for kind, u, c, x, ok in zip(_kinds(r), r["replan_update_ms"], checks, r["replan_ms"], _found(r)[1:]):
            if ok:
                (react if kind == "move" else improve).append(u + c + x)
    return {
        "tool_landmark": variant.label_tool, "env_landmark": variant.label_env,
        "success_rate": sum(bool(r["success"]) for r in runs) / (len(runs) + crashed) if runs or crashed
        else math.nan,
        "n_scenarios": len(runs) + int(crashed),
        "crashed": int(crashed),
        "collisions": int(sum(bool(r["contacts"]) for r in runs)),
        "mean_fraction_in_bowl": float(np.mean([r["fraction_in_bowl"] for r in runs])) if runs else math.nan,
        "learning_time_s": learning_time_s,
        "initial_ms": stats(init), "replan_ms": stats(rep),
        "build_ms": stats(build), "reaction_ms": stats(react), "improve_ms": stats(improve),
        "latency_mode": sorted({r.get("latency", "none") for r in runs}),
        **_tilt_stats(runs),
        "tracking_max_mm": max([r["tracking_max_mm"] for r in runs if "tracking_max_mm" in r], default=math.nan),
        "scenarios": [{"scenario": r["scenario"], "demo_seed": r.get("demo_seed", 0), "success": r["success"],
                       "reason": r["reason"], "fraction_in_bowl": r["fraction_in_bowl"]}
                      for r in sorted(runs, key=lambda r: (r.get("demo_seed", 0), r["scenario"]))],
    }


def _kinds(r: dict) -> list[str]:
    """Each re-plan's cause in run ``r``: "move" or "growth" (every one a move for a run logged
    before the anytime re-plans were told apart)."""
    return r.get("replan_kind") or ["move"] * len(r["replan_ms"])


def _found(r: dict) -> list[bool]:
    """Whether each plan of run ``r`` was found: the first plan, then each re-plan (its
    ``plan_statuses``; every one for a run logged without them)."""
    statuses = r.get("plan_statuses")
    if not statuses:
        return [True] * (1 + len(r["replan_ms"]))
    return [st == "ok" for st in statuses]


def _tilt_stats(runs: list[dict]) -> dict:
    """The tool's largest tilt against the demonstrations' mean (``sim.attitude``), over the runs
    that have it and moved (a run without a first plan never tilted: its 0° is no tilt error):
    ``tilt_error_deg`` and ``planned_tilt_error_deg`` as ``{median, p95}`` of the absolute error
    in degrees (what was reached, what was commanded), ``tilt_bias_deg`` the median signed error
    (negative: tilted less than the demonstrator)."""
    def errors(key):
        return [r[key] for r in runs if r.get(key) is not None and math.isfinite(r[key]) and _found(r)[0]]

    executed, planned = errors("tilt_error_deg"), errors("planned_tilt_error_deg")
    return {"tilt_error_deg": stats(np.abs(executed)), "planned_tilt_error_deg": stats(np.abs(planned)),
            "tilt_bias_deg": _pct(executed, 50)}


def spread(cells: list[dict]) -> dict:
    """``{variant: {mean, sd, min, max, cells}}`` of the success rates over ``cells`` (each
    ``{"variants": {name: summary}}``; cells without runs of a variant are left out, a cell whose
    runs all crashed counts at 0%; ``sd`` is the sample standard deviation, NaN for one cell)."""
    names = {n for c in cells for n in c["variants"]}
    out = {}
    for name in sorted(names):
        rates = [c["variants"][name]["success_rate"] for c in cells
                 if name in c["variants"] and c["variants"][name]["n_scenarios"]]
        out[name] = {"mean": float(np.mean(rates)) if rates else math.nan,
                     "sd": float(np.std(rates, ddof=1)) if len(rates) > 1 else math.nan,
                     "min": min(rates, default=math.nan), "max": max(rates, default=math.nan),
                     "cells": len(rates)}
    return out


def strict_json(x):
    """``x`` with every NaN or infinite float as None: ``results.json`` is strict JSON (``null``
    where nothing was measured, e.g. no re-plans), readable by jq and JavaScript."""
    if isinstance(x, dict):
        return {k: strict_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [strict_json(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _ms(stats: dict | None, key: str = "median") -> str:
    """``stats[key]`` (of ``{median, p95, mean}``) in whole ms, '-' when missing or NaN."""
    x = (stats or {}).get(key, math.nan)
    return "-" if x is None or math.isnan(x) else f"{x:.0f}ms"


def _deg(stats: dict | None) -> str:
    """``{median, p95}`` in degrees as 'median / p95', '-' when missing or NaN."""
    m, p = ((stats or {}).get(k) for k in ("median", "p95"))
    if m is None or p is None or math.isnan(m) or math.isnan(p):
        return "-"
    return f"{m:.0f} / {p:.0f} deg"


def _success(v: dict, s: dict | None) -> str:
    """A variant's success: its rate, or over several cells their mean ± standard deviation."""
    if s and s.get("cells", 0) > 1:
        return f"{s['mean']:.0%} ± {s['sd']:.0%}"
    return "-" if v["success_rate"] is None or math.isnan(v["success_rate"]) else f"{v['success_rate']:.0%}"


def format_table(results: dict, task: str, latency: str | None = None, cells: dict | None = None) -> str:
    """The paper's table (``results``: ``{variant: summary}``) with the paper's success rate beside
    ours: medians of the latencies (``summarize``); '-' where none was measured. ``latency``: the
    evaluation's latency mode, named under the table; ``cells``: a sweep's ``spread``, whose
    mean ± sd over cells then stands in the success column."""
    head = f"{'Tool landmark':<14} {'Environment landmark':<21} {'Success':>11} {'Paper':>6} {'Learning':>9} " \
           f"{'Plan (init)':>12} {'Replan':>9} {'Reaction':>9} {'mean':>7} {'Tilt error':>12}"
    n = max((v['n_scenarios'] for v in results.values()), default=0)
    n_cells = max((s.get("cells", 0) for s in (cells or {}).values()), default=1)
    what = f"{n} runs over {n_cells} cells (scenario sets x demonstration draws)" if n_cells > 1 else f"{n} scenarios"
    lines = [f"{task}: success rate over {what}", head, "-" * len(head)]
    paper = PAPER_SUCCESS.get(task, {})
    for name, v in results.items():
        p = f"{paper[name]:.0%}" if name in paper else "-"
        lines.append(f"{v['tool_landmark']:<14} {v['env_landmark']:<21} {_success(v, (cells or {}).get(name)):>11} "
                     f"{p:>6} {v['learning_time_s']:>8.1f}s {_ms(v['initial_ms']):>12} {_ms(v['replan_ms']):>9} "
                     f"{_ms(v.get('reaction_ms')):>9} {_ms(v.get('reaction_ms'), 'mean'):>7} "
                     f"{_deg(v.get('tilt_error_deg')):>12}")
    lines.append("Plan, Replan and Reaction: medians, the Reaction's mean beside it; Plan and Replan: the search "
                 "alone (the paper's latency), of the first plan and of the re-plans after a sensed move; Reaction: "
                 "such a re-plan with the landmark update and the check of the plan being followed before it (the "
                 "anytime re-plans while the roadmap grows after a far move: improve_ms in results.json); "
                 f"the paper: {PAPER_LATENCY_MS.get(task, '-')} ms on 12 cores, a mean over 10 scenarios; Tilt error: the "
                 "tool's largest tilt against the demonstrations' mean, |median| / p95 in degrees")
    crashed = sum(v.get("crashed", 0) for v in results.values())
    if crashed:
        lines.append(f"{crashed} run(s) crashed twice and count as failures: their errors are in runs.jsonl")
    if latency is not None:
        lines.append(f"latency mode: {latency} ({describe_latency(parse_latency(latency))})")
    return "\n".join(lines)
