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
