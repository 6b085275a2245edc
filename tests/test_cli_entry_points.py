"""The benchmarks on bad arguments, and every program's output piped into a reader that stops.

Bad arguments to ``benchmarks/*.py``: one line on stderr naming the problem, exit status 2, no
usage block (``lfd.cli.ArgumentParser``); each benchmark's ``main`` is called in this process.
Output into a closed pipe (``train.py --help | head -1``): no traceback and no "Exception ignored"
on stderr, exit status ``lfd.cli.EXIT_BROKEN_PIPE`` (141); these need the real script in a
subprocess (the interpreter's own flush at exit is under test), all started together from one
module fixture.
"""

from __future__ import annotations

import importlib.util
import math
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from lfd.cli import EXIT_BROKEN_PIPE
from helpers import run_cli, synthetic_demo_dir

ROOT = Path(__file__).resolve().parent.parent

# (id, argv, distinctive fragment of the one stderr line)
OUT = "{tmp}/bench.json"  # where a benchmark that did start would write (never runs/bench)
BAD = [
    ("collision-not-an-int", ["benchmarks/collision.py", "--n", "many", "--out", OUT],
     "argument --n: invalid int value: 'many'"),
    ("collision-task", ["benchmarks/collision.py", "--task", "stir", "--out", OUT],
     "argument --task: invalid choice: 'stir'"),
    ("collision-runs-0", ["benchmarks/collision.py", "--runs", "0", "--out", OUT], "--n and --runs must be at least 1"),
    ("planning-not-an-int", ["benchmarks/planning.py", "--moves", "x", "--out", OUT],
     "argument --moves: invalid int value: 'x'"),
    ("planning-few-moves", ["benchmarks/planning.py", "--moves", "5", "--out", OUT], "--moves must be at least 20, got 5"),
    ("learning-not-an-int", ["benchmarks/learning.py", "--runs", "x"], "argument --runs: invalid int value: 'x'"),
    ("learning-restarts-0", ["benchmarks/learning.py", "--restarts", "0"], "--restarts must be at least 1, got 0"),
    ("collision-abbreviated", ["benchmarks/collision.py", "--ru", "3", "--out", OUT],
     "unrecognized arguments: --ru 3"),
    ("soak-not-an-int", ["benchmarks/soak.py", "--replans", "x", "--out", "{tmp}"],
     "argument --replans: invalid int value: 'x'"),
    ("reaction-scenes-0", ["benchmarks/reaction.py", "--scenes", "0", "--out", OUT], "--scenes must be at least 1, got 0"),
    ("reaction-scenes-overlap", ["benchmarks/reaction.py", "--scenes", "100004", "--out", OUT],
     "--scenes must be at most 100003"),
    ("reaction-roadmap", ["benchmarks/reaction.py", "--roadmap-size", "5", "--out", OUT],
     "--roadmap-size must be in [10, 100000], got 5"),
]

# (id, argv): stdout is a pipe whose reader has already gone
PIPED = [
    ("train-help", ["train.py", "--help"]),
    ("plan-help", ["plan.py", "--help"]),
    ("collision-help", ["benchmarks/collision.py", "--help"]),
    ("train-progress", None),  # train.py's first progress line, mid-run (set up in the fixture)
]


def _run(argv, stdout=subprocess.PIPE):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}  # a shell's default buffering
    return subprocess.run([sys.executable, *argv], cwd=ROOT, stdout=stdout, stderr=subprocess.PIPE, text=True,
                          timeout=180, env=env)


def _run_into_closed_pipe(argv):
    """Run with stdout a pipe nobody reads any more (``| head -1`` after its line)."""
    r, w = os.pipe()
    os.close(r)
    try:
        return _run(argv, stdout=w)
    finally:
        os.close(w)


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    demos = synthetic_demo_dir(tmp_path_factory.mktemp("demos"), 2, 4, 2, (3, 4))
    out = tmp_path_factory.mktemp("out")
    piped = dict(PIPED)
    piped["train-progress"] = ["train.py", "--task", "powder", "--demos", str(demos), "--out", str(out),
                               "--restarts", "1", "--time-steps", "4"]
    with ThreadPoolExecutor(max_workers=3) as pool:
        pipes = {cid: pool.submit(_run_into_closed_pipe, argv) for cid, argv in piped.items()}
        return {cid: f.result() for cid, f in pipes.items()}


def test_cases_are_distinct():
    assert len({c[0] for c in BAD}) == len({c[2] for c in BAD}) == len(BAD)


def _benchmark_main(script: str):
    """``main`` of ``benchmarks/<name>.py``, loaded from its file (benchmarks/ is not a package)."""
    name = f"_bench_{Path(script).stem}"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, ROOT / script)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # its dataclasses look their module up there
        spec.loader.exec_module(module)
    return sys.modules[name].main


@pytest.mark.parametrize("cid,argv,fragment", BAD, ids=[c[0] for c in BAD])
def test_benchmark_bad_argument_one_line_exit_2(tmp_path, capsys, cid, argv, fragment):
    r = run_cli(_benchmark_main(argv[0]), argv[0], [a.format(tmp=tmp_path) for a in argv[1:]], capsys)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and "usage:" not in r.stderr
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(f"{argv[0]}: error: "), lines[0]
    assert fragment in lines[0], lines[0]


@pytest.mark.parametrize("cid", [c[0] for c in PIPED])
def test_closed_pipe_ends_quietly(results, cid):
    r = results[cid]
    assert r.stderr == "", r.stderr  # no traceback, no "Exception ignored ... BrokenPipeError"
    assert r.returncode == EXIT_BROKEN_PIPE


def test_plan_latency_modes(monkeypatch):
    """plan.py --latency: measured (default), none, or seconds >= 0; anything else is a usage error."""
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1]))
    import plan
    from lfd.cli import UsageError
    assert plan.parse(["--model", "x"]).latency == "measured"
    assert plan.parse(["--model", "x", "--latency", "none"]).latency == "none"
    assert plan.parse(["--model", "x", "--latency", "0.25"]).latency == "0.25"
    for bad in ("soon", "-1", "nan", "inf"):
        with pytest.raises(UsageError, match="--latency"):
            plan.parse(["--model", "x", "--latency", bad])


@pytest.mark.parametrize("executed,code", [(True, 0), (False, 1)])
def test_one_plan_executed_exits_1_when_the_execution_fails(tmp_path, monkeypatch, capsys, executed, code):
    """``lfd-plan --model M --execute``: a plan found but an execution that spilled or hit something
    is a failure of the command (exit 1), not only a plan that was not found."""
    from types import SimpleNamespace

    import numpy as np

    import sim.model_check
    import sim.runner
    from sim import plan_cli

    res = SimpleNamespace(ok=True, configurations=np.zeros((2, 7)), time_steps=np.array([0, 1]), cost=1.0)
    report = dict(status="ok", cost=1.0, waypoints=2, latency_ms=5.0, edges_evaluated=3, roadmap_vertices=4,
                  roadmap_build_s=0.1, execution=dict(success=executed, reason="ok" if executed else "spilled",
                                                      fraction_in_bowl=0.9 if executed else 0.2, n_replans=0,
                                                      executed_tilt_deg=120.0, planned_tilt_deg=121.0))
    model = SimpleNamespace(task=SimpleNamespace(dt=0.1))
    monkeypatch.setattr(sim.model_check, "load_checked_model", lambda *a, **kw: (SimpleNamespace(time_steps=24), "powder"))
    monkeypatch.setattr(sim.runner, "plan_scenario", lambda *a, **kw: (report, res, model))
    d = tmp_path / "model"
    d.mkdir()
    assert plan_cli.main(["--model", str(d), "--execute", "--out", str(tmp_path / "o")]) == code
    assert ("execution: success" if executed else "execution: failure (spilled)") in capsys.readouterr().out



def test_no_plan_says_why_and_what_was_skipped_and_writes_strict_json(tmp_path, monkeypatch, capsys):
    """``lfd-plan --model M --execute --plot`` without a plan printed only ``plan: unreachable  cost
    inf``: the reason was in the JSON alone, --execute and --plot were skipped without a word, and
    the JSON held ``Infinity`` (not JSON: JavaScript's parser refuses it, jq reads 1.8e308)."""
    import json
    from types import SimpleNamespace

    import numpy as np

    import sim.model_check
    import sim.runner
    from sim import plan_cli

    why = "the arm cannot reach the tool-point targets of time step(s) [5, 6]"
    res = SimpleNamespace(ok=False, status="unreachable", message=why, configurations=np.zeros((0, 7)),
                          time_steps=np.zeros(0, dtype=int), cost=math.inf)
    report = dict(status="unreachable", message=why, cost=math.inf, waypoints=0, latency_ms=5.0, edges_evaluated=0,
                  roadmap_vertices=4, roadmap_build_s=0.1)
    monkeypatch.setattr(sim.model_check, "load_checked_model", lambda *a, **kw: (SimpleNamespace(time_steps=24), "powder"))
    monkeypatch.setattr(sim.runner, "plan_scenario", lambda *a, **kw: (report, res, SimpleNamespace(task=SimpleNamespace(dt=0.1))))
    d = tmp_path / "model"
    d.mkdir()
    assert plan_cli.main(["--model", str(d), "--execute", "--plot", "--out", str(tmp_path / "o")]) == 1
    out = capsys.readouterr().out
    assert f"no plan: {why}; --execute and --plot skipped" in out
    text = (tmp_path / "o" / "plan_scenario0.json").read_text()
    assert "Infinity" not in text and json.loads(text)["cost"] is None


def test_a_write_the_storage_refuses_is_one_line_with_status_1(capsys):
    """A full disk (ENOSPC) was a traceback from train.py, lfd-import and plan.py; now one line
    naming the file, status 1 (the machine's fault, not the input's). Other OS errors still raise."""
    import errno

    import pytest

    from lfd.cli import run_main

    def full(argv):
        raise OSError(errno.ENOSPC, "No space left on device", "/out/model.pt")

    with pytest.raises(SystemExit) as info:
        run_main(full, [], prog="lfd-train")
    assert info.value.code == 1
    err = capsys.readouterr().err
    assert err.startswith("lfd-train: error: ") and err.count("\n") == 1, err
    assert "No space left on device" in err and "/out/model.pt" in err, err

    def broken(argv):
        raise OSError(errno.EIO, "Input/output error")

    with pytest.raises(OSError, match="Input/output"):
        run_main(broken, [], prog="lfd-train")
