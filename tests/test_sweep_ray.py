"""The same sweep on local processes and on a local Ray with 2 CPUs gives the same per-scenario
outcomes: real runs (a learned powder model planned and executed in PyBullet, the world frozen
so that they are deterministic), the model's files shipped to the Ray tasks through the object
store. Ray is the optional extra ``[ray]`` (``make`` installs it)."""

from __future__ import annotations

import json
import shutil

import pytest

import sim.evaluate as ev

pytest.importorskip("ray")

KEYS = ("success", "reason", "fraction_in_bowl", "fraction_spilled", "n_replans", "plan_statuses",
        "edges_evaluated", "roadmap_vertices", "contacts")


def test_ray_and_local_executors_give_the_same_outcomes(tmp_path, small_powder_model):
    models = tmp_path / "models"
    shutil.copytree(small_powder_model, models / "learn-learn")
    settings = ev.EvalSettings(task="powder", n_scenarios=2, seeds=(0,), roadmap_size=300, workers=2,
                               variants=("learned+learned",), latency="none")
    rows = {}
    for executor in ("local", "ray"):
        out = tmp_path / executor
        payload = ev.evaluate(ev.EvalSettings(**{**settings.__dict__, "executor": executor}), out, models)
        assert payload["executor"] == executor and payload["crashed"] == []
        logged = [json.loads(x) for x in (out / "runs.jsonl").read_text().splitlines()]
        assert len(logged) == 2 and all((out / r["task_point_path"]).is_file() for r in logged)
        rows[executor] = {r["scenario"]: {k: r[k] for k in KEYS} for r in logged}
    assert rows["ray"] == rows["local"]
    assert all(r["plan_statuses"][0] == "ok" for r in rows["ray"].values())
