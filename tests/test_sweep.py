"""Evaluation sweeps: jobs retried once and crashes logged, a worker that dies, a grid of scenario
sets x demonstration draws with its spread, and a sweep killed half way (SIGINT to a real
``evaluate`` in a subprocess with two worker processes) that ``--resume`` completes into the
results of an uninterrupted run. The runs are ``sweep_fakes.run`` (no simulation); the real
simulation on Ray is in ``test_sweep_ray``."""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest

import sim.evaluate as ev
import sweep_fakes
from lfd.cli import UsageError
from sim.report import format_table, summarize
from sim.sweep import Job, LocalExecutor, run_jobs

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent
TASK = "powder"


@pytest.fixture
def models(tmp_path) -> Path:
    root = tmp_path / "models"
    for v in ev.VARIANTS:
        d = ev.model_dir_for(root, v)
        d.mkdir(parents=True, exist_ok=True)
        (d / "model.pt").write_bytes(b"")
        (d / "config.json").write_text("{}")
    return root


@pytest.fixture
def fakes(monkeypatch):
    monkeypatch.setattr(ev, "draw_scenarios", sweep_fakes.draw)
    monkeypatch.setattr(ev, "run_one", sweep_fakes.run)


def _settings(**kw) -> ev.EvalSettings:
    base = dict(task=TASK, n_scenarios=5, seeds=(0, 1), roadmap_size=10, workers=1,
                variants=("learned+learned",), latency="none")
    return ev.EvalSettings(**{**base, **kw})


def _collect(fn, jobs, executor):
    got = {}
    run_jobs(fn, jobs, lambda job, result, error: got.__setitem__(job.key, (result, error)), executor)
    return got


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failing_job_is_retried_once_then_reported(tmp_path, workers):
    jobs = [Job((k,), (str(tmp_path), k, fails)) for k, fails in (("ok", 0), ("once", 1), ("always", 5))]
    got = _collect(sweep_fakes.flaky, jobs, LocalExecutor(workers))
    assert got[("ok",)] == ("ok", None) and got[("once",)] == ("once", None)
    assert got[("always",)] == (None, "RuntimeError: always failed on purpose")  # one line
    calls = {k: (tmp_path / f"{k}.calls").stat().st_size for k in ("ok", "once", "always")}
    assert calls == {"ok": 1, "once": 2, "always": 2}


def test_a_worker_that_dies_loses_only_its_jobs_and_they_are_retried(tmp_path):
    jobs = [Job((k,), (str(tmp_path), k, 1 if k == "dies" else 0, "die")) for k in ("a", "dies", "b", "c")]
    got = _collect(sweep_fakes.flaky, jobs, LocalExecutor(2))
    assert got == {(k,): (k, None) for k in ("a", "dies", "b", "c")}
    assert (tmp_path / "dies.calls").stat().st_size == 2


def test_a_job_that_always_kills_its_worker_is_the_only_one_charged(tmp_path):
    """A dead worker fails the whole pool: its jobs run again one at a time, so the others
    succeed and only the job that kills a worker on its own is reported."""
    jobs = [Job((k,), (str(tmp_path), k, 9 if k == "killer" else 0, "die")) for k in ("a", "killer", "b", "c", "d")]
    got = _collect(sweep_fakes.flaky, jobs, LocalExecutor(2))
    assert {k for (k,), (r, e) in got.items() if e is None} == {"a", "b", "c", "d"}
    assert got[("killer",)][0] is None and "BrokenProcessPool" in got[("killer",)][1]


def test_grid_cells_spread_and_table(tmp_path, models, fakes, monkeypatch):
    """Two scenario sets x two demonstration draws: draw 2's models are trained (on demand, on
    demonstrations drawn with seed 2), every cell has its line and the table shows mean ± sd."""
    trained, drawn = [], []
    monkeypatch.setattr(ev, "train_main", sweep_fakes.fake_train(trained))
    monkeypatch.setattr(ev, "ensure_demos", lambda task, folder, seed: drawn.append((task, Path(folder), seed)))
    monkeypatch.chdir(tmp_path)
    payload = ev.evaluate(_settings(demo_seeds=(0, 2)), tmp_path / "eval", models)
    assert drawn == [(TASK, Path("runs/demos/powder-seed2"), 2)]
    assert len(trained) == 1 and trained[0][trained[0].index("--demos") + 1] == "runs/demos/powder-seed2"
    assert (models / "demos-seed2" / "learn-learn" / "model.pt").is_file()
    cells = payload["cells"]
    assert [(c["seed"], c["demo_seed"]) for c in cells] == [(0, 0), (0, 2), (1, 0), (1, 2)]
    rates = []
    for c in cells:
        seeds = [S * 100_003 + i for S in [c["seed"]] for i in range(5)]
        expect = sum(sweep_fakes.outcome("learned+learned", s) for s in seeds) / 5
        assert c["variants"]["learned+learned"]["success_rate"] == pytest.approx(expect)
        rates.append(expect)
    s = payload["spread"]["learned+learned"]
    assert s["cells"] == 4 and s["mean"] == pytest.approx(sum(rates) / 4)
    assert payload["variants"]["learned+learned"]["n_scenarios"] == 20
    table = format_table(payload["variants"], TASK, "none", cells=payload["spread"])
    assert f"{s['mean']:.0%} ± {s['sd']:.0%}" in table and "100%" in table  # ours and the paper's
    # the mode's words under the table (every mode was said to charge plans while the robot moves on)
    assert table.endswith("latency mode: none (the world waits for the planner: plans cost no simulated time)")
    assert format_table(payload["variants"], TASK, 0.5).endswith(
        "latency mode: 0.5 (each plan costs 0.5 s of simulated time, while the robot moves on)")
    assert format_table(payload["variants"], TASK, "measured").endswith(
        "latency mode: measured (each plan costs its wall-clock time in simulated time, while the robot moves on)")
    rows = [json.loads(line) for line in (tmp_path / "eval" / "runs.jsonl").read_text().splitlines()]
    assert {(r["demo_seed"], r["base_seed"]) for r in rows} == {(0, 0), (0, 1), (2, 0), (2, 1)}
    paths = {r["task_point_path"] for r in rows}
    assert len(paths) == 20 and all((tmp_path / "eval" / p).is_file() for p in paths)
    with pytest.raises(UsageError, match="demonstration draws other than 0"):
        ev.evaluate(_settings(demo_seeds=(3,)), tmp_path / "eval2", models, demos=tmp_path)


def test_a_bowl_move_is_given_to_every_scenario_and_logged(tmp_path, models, fakes, monkeypatch):
    """``--move-bowl``: every scenario gets a move (a stand-in for ``with_bowl_move``), at a
    share of the task that each run turns into its own model's time step (models of different T
    share the scenes), and the runs are logged with the setting."""
    def fake_move(sc, reach):
        return replace(sc, bowl_after=(0.7, 0.2), move_at=0.25)

    monkeypatch.setattr(ev, "with_bowl_move", fake_move)
    monkeypatch.setattr(ev, "DumpReach", lambda task: contextlib.nullcontext(None))
    both = ("learned+learned", "learned+manual")
    payload = ev.evaluate(_settings(move_bowl=True, seeds=(0,), variants=both), tmp_path / "eval", models)
    assert payload["move_bowl"] is True
    assert [(sc["move_at"], sc["bowl_after"]) for sc in payload["scenario_set"]] == [(0.25, [0.7, 0.2])] * 5
    rows = [json.loads(line) for line in (tmp_path / "eval" / "runs.jsonl").read_text().splitlines()]
    assert len(rows) == 10 and all(r["settings"]["move_bowl"] is True for r in rows)


def test_crashed_runs_are_logged_counted_apart_and_run_again_on_resume(tmp_path, models, fakes, monkeypatch):
    bad = 100_003 + 2  # scenario 2 of base seed 1

    def crashing(task, scenario, variant, *args, **kw):
        if scenario.seed == bad:
            raise ValueError("the planner fell over")
        return sweep_fakes.run(task, scenario, variant, *args, **kw)

    monkeypatch.setattr(ev, "run_one", crashing)
    out = tmp_path / "eval"
    payload = ev.evaluate(_settings(), out, models)
    assert payload["crashed"] == [{"variant": "learned+learned", "demo_seed": 0, "scenario": bad,
                                   "error": "ValueError: the planner fell over"}]
    v = payload["variants"]["learned+learned"]
    # a crashed run is a scene not done: a failure in the rate, not a smaller denominator
    finished = v["scenarios"]  # the finished runs' scenes
    assert v["n_scenarios"] == 10 and v["crashed"] == 1 and len(finished) == 9
    assert v["success_rate"] == pytest.approx(sum(sc["success"] for sc in finished) / 10)
    every_run_crashed = summarize([], ev.VARIANTS[0], math.nan, crashed=2)
    assert every_run_crashed["success_rate"] == 0.0 and every_run_crashed["n_scenarios"] == 2
    assert "1 run(s) crashed twice" in format_table(payload["variants"], TASK)
    errors = [r for r in map(json.loads, (out / "runs.jsonl").read_text().splitlines()) if "error" in r]
    assert len(errors) == 1 and errors[0]["scenario"] == bad and errors[0]["attempts"] == 2
    with pytest.raises(UsageError, match="pass --resume"):
        ev.evaluate(_settings(), out, models)  # a logged folder is not overwritten or mixed
    monkeypatch.setattr(ev, "run_one", sweep_fakes.run)
    calls = []
    monkeypatch.setattr(ev, "run_one", lambda *a, **kw: calls.append(a[1].seed) or sweep_fakes.run(*a, **kw))
    payload = ev.evaluate(_settings(), out, models, resume=True)
    assert calls == [bad] and payload["crashed"] == [] and payload["variants"]["learned+learned"]["n_scenarios"] == 10



def test_the_command_exits_1_when_a_run_crashed_and_0_once_resumed(tmp_path, models, fakes, monkeypatch, capsys):
    """A failed scene is a result (exit 0); a run that crashed twice has none: ``lfd-plan --evaluate``
    prints the table of the others and exits 1, naming ``--resume``, which then completes it."""
    import sim.model_check
    from sim import plan_cli

    def crashing(task, scenario, variant, *args, **kw):
        if scenario.seed == 1:
            raise ValueError("the planner fell over")
        return sweep_fakes.run(task, scenario, variant, *args, **kw)

    monkeypatch.setattr(sim.model_check, "check_models_for_task", lambda *a, **kw: [])
    monkeypatch.setattr(ev, "run_one", crashing)
    argv = ["--evaluate", "--task", TASK, "--scenarios", "3", "--workers", "1", "--latency", "none",
            "--variants", "learned+learned", "--models", str(models), "--out", str(tmp_path / "eval")]
    assert plan_cli.main(argv) == 1
    err = capsys.readouterr().err
    assert "1 run(s) crashed twice" in err and "--resume" in err
    monkeypatch.setattr(ev, "run_one", sweep_fakes.run)
    assert plan_cli.main([*argv, "--resume"]) == 0



_SWEEP = """
import signal, sys
# Ctrl-C as a terminal delivers it: the test process may run with SIGINT ignored (a shell
# without job control starts its background commands so; no test changes the handler, checked
# after every test of the suite), and an ignored signal stays ignored across exec (seen: the
# sweep ran all ten runs after the signal and exited 0)
signal.signal(signal.SIGINT, signal.default_int_handler)
signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT])
sys.path.insert(0, {tests!r})
from pathlib import Path
import sim.evaluate as ev, sweep_fakes
ev.draw_scenarios, ev.run_one = sweep_fakes.draw, sweep_fakes.run
settings = ev.EvalSettings(task="powder", n_scenarios=5, seeds=(0, 1), roadmap_size=10, workers=2,
                           variants=("learned+learned",), latency="none")
ev.evaluate(settings, Path({out!r}), Path({models!r}), resume=True)
"""


def _comparable(payload: dict) -> dict:
    return {k: payload[k] for k in ("variants", "cells", "spread", "crashed", "scenario_set")}


def test_a_sweep_killed_half_way_resumes_to_the_uninterrupted_results(tmp_path, models, fakes):
    out = tmp_path / "eval"
    script = _SWEEP.format(tests=str(TESTS), out=str(out), models=str(models))
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    log = out / "runs.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if log.is_file() and len(log.read_text().splitlines()) >= 4:
            break
        time.sleep(0.02)
    assert proc.poll() is None, proc.communicate()
    os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C reaches the driver and its workers
    _, err = proc.communicate(timeout=60)
    lines = log.read_text().splitlines()
    assert proc.returncode != 0 and "KeyboardInterrupt" in err, (proc.returncode, len(lines), err[-2000:])
    assert 4 <= len(lines) < 10 and not (out / "results.json").exists()  # half way, nothing summarized

    resumed = ev.evaluate(replace(_settings(), workers=2), out, models, resume=True)
    rows = [json.loads(x) for x in log.read_text().splitlines()]
    assert sorted(r["scenario"] for r in rows) == sorted({r["scenario"] for r in rows})  # none run twice
    assert len(rows) == 10
    whole = ev.evaluate(_settings(), tmp_path / "whole", models)
    assert _comparable(resumed) == _comparable(whole)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with contextlib.suppress(OSError):  # a zombie (a child of this process not yet reaped) is not running
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    return True


def _pids(folder: Path, n: int, timeout: float = 60.0) -> list[int]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and len(list(folder.glob("*.pid"))) < n:
        time.sleep(0.02)
    return [int(f.stem) for f in folder.glob("*.pid")]


def test_a_cancelled_pool_terminates_the_workers_of_jobs_in_flight(tmp_path):
    """Ctrl-C or SIGTERM in the driver cancels the pool (``run_jobs``' ``close(cancel=True)``):
    the workers still running a job were left running it (for nobody, 60 s here); now they end."""
    ex = LocalExecutor(2)
    # after the quick job, each of the two workers runs a slow one (whichever ran the quick one)
    jobs = [Job(("quick",), (str(tmp_path), 0.0)), Job(("slow", 1), (str(tmp_path), 60.0)),
            Job(("slow", 2), (str(tmp_path), 60.0))]
    it = ex.run(sweep_fakes.sleeper, jobs)
    job, _, e = next(it)
    assert job.key == ("quick",) and e is None
    pids = _pids(tmp_path, 2)
    assert len(pids) == 2 and all(_alive(p) for p in pids)
    tic = time.monotonic()
    ex.close(cancel=True)
    assert not any(_alive(p) for p in pids) and time.monotonic() - tic < 10.0


_DRIVER = """
import sys, time
sys.path.insert(0, {tests!r})
import sweep_fakes
from sim.sweep import Job, LocalExecutor, run_jobs
run_jobs(sweep_fakes.sleeper, [Job((i,), ({pids!r}, 60.0)) for i in range(2)], lambda *a: None, LocalExecutor(2))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_workers_end_with_a_driver_killed_outright(tmp_path, sig):
    """``kill <driver>`` (SIGTERM, which the bare library does not catch) or SIGKILL: the driver
    ends at once and its two workers went on with their jobs, then waited for ever on a pipe."""
    proc = subprocess.Popen([sys.executable, "-c", _DRIVER.format(tests=str(TESTS), pids=str(tmp_path))],
                            cwd=ROOT, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    pids = _pids(tmp_path, 2)
    assert len(pids) == 2 and all(_alive(p) for p in pids), proc.communicate(timeout=5)
    os.kill(proc.pid, sig)  # the driver only, not its process group
    proc.communicate(timeout=30)
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.05)
    left = [p for p in pids if _alive(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    assert not left


def test_an_interrupted_evaluation_names_the_command_that_goes_on(tmp_path, models, monkeypatch, capsys):
    """SIGTERM ended ``lfd-plan --evaluate`` without a word (the workers left running); SIGTERM and
    Ctrl-C now print where the finished runs are and the command that resumes them, status 128 +
    the signal."""
    import sim.model_check
    from lfd.learning.checkpoint import Interrupted
    from sim import plan_cli

    def interrupted(*a, **kw):
        raise Interrupted(signal.SIGTERM)

    monkeypatch.setattr(sim.model_check, "check_models_for_task", lambda *a, **kw: [])
    monkeypatch.setattr(ev, "evaluate", interrupted)
    argv = ["--evaluate", "--task", TASK, "--scenarios", "3", "--workers", "1", "--latency", "none",
            "--variants", "learned+learned", "--models", str(models), "--out", str(tmp_path / "eval")]
    assert plan_cli.main(argv, prog="lfd-plan") == 128 + signal.SIGTERM
    err = capsys.readouterr().err.strip()
    assert err == (f"lfd-plan: interrupted by SIGTERM; the finished runs are in {tmp_path / 'eval' / 'runs.jsonl'}; "
                   f"go on with: lfd-plan {' '.join(argv)} --resume")


def test_a_training_interrupted_inside_an_evaluation_goes_on_from_its_checkpoint(tmp_path, models, monkeypatch,
                                                                                  capsys):
    """SIGTERM while ``--evaluate`` trained a variant: the training kept its checkpoint, but the
    command said only "error: ... stopped with exit status 143", and the next run trained that
    variant again from its first restart. Now it says how to go on, and the next run resumes."""
    import sim.model_check
    from sim import plan_cli

    def interrupted(*a, **kw):
        raise ev.TrainingFailed("training the learned+learned model (learn-learn) stopped with exit status 143", 143)

    monkeypatch.setattr(sim.model_check, "check_models_for_task", lambda *a, **kw: [])
    monkeypatch.setattr(ev, "evaluate", interrupted)
    argv = ["--evaluate", "--task", TASK, "--workers", "1", "--variants", "learned+learned",
            "--models", str(models), "--out", str(tmp_path / "eval")]
    assert plan_cli.main(argv, prog="lfd-plan") == 143
    assert capsys.readouterr().err.strip() == f"lfd-plan: interrupted while training; go on with: lfd-plan {' '.join(argv)} --resume"

    seen = []
    monkeypatch.setattr(ev, "train_main", lambda argv: seen.append(list(argv)) or 0)
    v = next(x for x in ev.VARIANTS if x.name == "learned+learned")
    out = ev.model_dir_for(tmp_path / "fresh", v)
    ev.ensure_model(TASK, tmp_path / "fresh", None, v)
    out.mkdir(parents=True, exist_ok=True)
    (out / "checkpoint.json").write_text("{}")  # what an interrupted training leaves
    ev.ensure_model(TASK, tmp_path / "fresh", None, v)
    assert "--resume" not in seen[0] and seen[1][-1] == "--resume"


def test_an_unreachable_ray_address_is_refused_before_any_training(tmp_path, monkeypatch):
    pytest.importorskip("ray")
    trained = []
    monkeypatch.setattr(ev, "train_main", sweep_fakes.fake_train(trained))
    with pytest.raises(UsageError, match="--address 127.0.0.1:1: no Ray cluster answers there"):
        ev.evaluate(_settings(executor="ray", address="127.0.0.1:1"), tmp_path / "eval", tmp_path / "models")
    assert trained == [] and not (tmp_path / "models").exists()
