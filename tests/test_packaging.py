"""Packaging: setup.py's console scripts, the one version, the distribution's name and
requirements, the constraints file, and that no repository script is run through a subprocess
(train.py and plan.py are thin wrappers of library functions, which ``make demo`` calls in-process).
"""

from __future__ import annotations

import ast
import importlib
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _setup_call():
    """``(module tree, the setup(...) call's keywords)`` of setup.py, read without running it."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "setup")
    return tree, {k.arg: k.value for k in call.keywords}


def test_console_scripts_resolve_to_callables():
    tree, _ = _setup_call()
    scripts = next(ast.literal_eval(n.value) for n in tree.body
                   if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", "") == "CONSOLE_SCRIPTS")
    names = {}
    for spec in scripts:
        name, target = (x.strip() for x in spec.split("="))
        module, func = target.split(":")
        names[name] = getattr(importlib.import_module(module), func)
        assert callable(names[name]), spec
    assert set(names) == {"lfd-train", "lfd-plan", "lfd-import"}
    assert names["lfd-train"].__module__.startswith("lfd.")  # the library's: no simulator needed
    assert names["lfd-import"].__module__.startswith("lfd.")
    assert names["lfd-plan"].__module__.startswith("sim.")


def test_setup_declares_the_distribution():
    """One version (lfd.__version__, parsed by setup.py without importing lfd), a distribution name
    that is not PyPI's other 'lfd', and the Baxter URDF's package in the plain install."""
    import re
    import lfd
    tree, kw = _setup_call()
    fn = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "read_version")
    ns = {"re": re, "Path": Path, "HERE": ROOT}
    exec(compile(ast.Module(body=[fn], type_ignores=[]), "setup.py", "exec"), ns)
    assert ns["read_version"]() == lfd.__version__
    assert isinstance(kw["version"], ast.Call) and kw["version"].func.id == "read_version"
    assert ast.literal_eval(kw["name"]) == "lfd-landmarks"
    requires = ast.literal_eval(kw["install_requires"])
    assert any(r.startswith("example-robot-data") for r in requires)
    assert not any(r.startswith("pybullet") for r in requires)  # the simulator is the [sim] extra's
    pins = dict(line.split("==") for line in (ROOT / "constraints.txt").read_text().splitlines()
                if line and not line.startswith("#"))
    assert pins["torch"] == "2.13.0"
    for r in requires:
        assert re.split(r"[<>=!~ ]", r)[0].lower().replace("_", "-") in {k.lower().replace("_", "-") for k in pins}


def test_lfd_train_cli_imports_no_simulator():
    import subprocess
    code = ("import sys, lfd.train_cli\n"
            "lfd.train_cli.parse_args(['--task', 'powder'])\n"
            "bad = [m for m in sys.modules if m == 'pybullet' or m == 'sim' or m.startswith('sim.')]\n"
            "assert not bad, bad\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr


def test_no_lfd_module_names_the_simulator():
    """lfd never imports sim or PyBullet, not even lazily: every import statement and every
    string handed to an importer in lfd/ is checked."""
    offenders = []
    for path in sorted((ROOT / "lfd").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                names = [node.value] if re.fullmatch(r"(sim|pybullet)(\.\w+)*", node.value) else []
            offenders += [f"{path.relative_to(ROOT)}:{node.lineno}: {n}" for n in names
                          if n.split(".")[0] in ("sim", "pybullet")]
    assert not offenders, offenders


_GENERATED: list = []


def _fake_generator(task, out_dir, n, seed):
    """Stands in for sim.demos.generate behind a fake entry point: records its call."""
    _GENERATED.append((task, out_dir, n, seed))


def test_demonstrations_come_from_the_registered_generator(tmp_path, monkeypatch):
    """lfd-train finds the demonstration generator through the entry-point group that setup.py
    declares (the simulator's), and says what to do when none is installed."""
    import importlib.metadata as md

    from lfd.cli import UsageError
    from lfd.train_cli import DEMO_GENERATORS, ensure_demos

    _, kw = _setup_call()
    groups = dict(zip((ast.literal_eval(k) for k in kw["entry_points"].keys), kw["entry_points"].values))
    assert ast.literal_eval(groups[DEMO_GENERATORS]) == ["sim = sim.demos:generate"]
    # the environment this runs in (make test installs the package) resolves the real one
    installed = {ep.name: ep.value for ep in md.entry_points(group=DEMO_GENERATORS)}
    assert installed == {"sim": "sim.demos:generate"}, "reinstall the package: pip install -e ."
    ep = md.EntryPoint("fake", f"{__name__}:_fake_generator", DEMO_GENERATORS)
    monkeypatch.setattr(md, "entry_points", lambda group: [ep] if group == DEMO_GENERATORS else [])
    _GENERATED.clear()
    ensure_demos("pour", tmp_path / "d", 3)
    assert _GENERATED == [("pour", tmp_path / "d", 11, 3)]
    (tmp_path / "e").mkdir()
    (tmp_path / "e" / "demo_000.npz").write_bytes(b"")
    ensure_demos("pour", tmp_path / "e", 3)  # demonstrations there: nothing generated
    assert len(_GENERATED) == 1
    monkeypatch.setattr(md, "entry_points", lambda group: [])
    with pytest.raises(UsageError, match="no demonstration generator is installed"):
        ensure_demos("pour", tmp_path / "f", 3)


@pytest.mark.parametrize("path", ["lfd", "sim", "train.py", "plan.py"])
def test_no_repository_script_runs_in_a_subprocess(path):
    """The commands call library functions; a child process, where one is needed, runs a function
    (multiprocessing), never a script path."""
    files = [ROOT / path] if path.endswith(".py") else sorted((ROOT / path).rglob("*.py"))
    for f in files:
        text = f.read_text()
        assert not re.search(r"^\s*(import subprocess|from subprocess )", text, flags=re.M), f
        assert not re.search(r"\bos\.(system|popen|exec\w*|spawn\w*)\(", text), f


@pytest.mark.parametrize("script,module", [("train.py", "lfd.train_cli"), ("plan.py", "sim.plan_cli")])
def test_root_scripts_wrap_the_entry_functions(monkeypatch, script, module):
    monkeypatch.syspath_prepend(str(ROOT))
    wrapper = importlib.import_module(script[:-3])
    target = importlib.import_module(module)
    assert wrapper.main.func is target.main and wrapper.main.keywords == {"prog": script}
    assert len(ast.parse((ROOT / script).read_text()).body) <= 10  # thin: imports and a call


def test_demo_job_runs_its_stages_in_process(tmp_path, monkeypatch, capsys):
    """``make demo``: the demonstrations and the evaluation (which trains missing models) are
    library calls in this process, with outputs under ./runs of the working directory."""
    import sim.demo_job as job
    import sim.demos
    import sim.plan_cli
    calls = []

    def fake_demos(argv):
        calls.append(("demos", argv))
        out = Path(argv[argv.index("--out") + 1])
        out.mkdir(parents=True)
        (out / "demo_000.npz").write_bytes(b"")
        return 0

    monkeypatch.setattr(sim.demos, "main", fake_demos)
    monkeypatch.setattr(sim.plan_cli, "main", lambda argv: calls.append(("plan", argv)) or 0)
    monkeypatch.chdir(tmp_path)
    assert job.cli() == 0
    assert [c[0] for c in calls] == ["demos", "plan"]
    plan = calls[1][1]
    assert plan[:2] == ["--evaluate", "--task"] and plan[plan.index("--scenarios") + 1] == "10"
    assert plan[plan.index("--models") + 1] == str(Path("runs") / "powder" / "models")
    assert (tmp_path / "runs" / "demos" / "powder" / "demo_000.npz").is_file()
    calls.clear()
    monkeypatch.setattr(sim.plan_cli, "main", lambda argv: 2)
    assert job.cli() == 2 and not any(c[0] == "demos" for c in calls)  # demonstrations exist: kept
    assert "make demo: lfd-plan failed with exit status 2" in capsys.readouterr().err


def test_lfd_plan_without_pybullet_has_help_and_one_clear_line():
    """The plain install (no [sim] extra): ``lfd-plan --help`` works, and a command that needs the
    simulator stops with one line naming the extra (PyBullet hidden from a fresh interpreter)."""
    import subprocess
    code = ("import sys\n"
            "sys.modules['pybullet'] = None  # import pybullet now raises ImportError\n"
            "from lfd.cli import run_main\n"
            "from sim import plan_cli\n"
            "run_main(plan_cli.main, prog='lfd-plan')\n")
    help_ = subprocess.run([sys.executable, "-c", code, "--help"], capture_output=True, text=True, timeout=120)
    assert help_.returncode == 0 and "--evaluate" in help_.stdout, help_.stderr
    r = subprocess.run([sys.executable, "-c", code, "--evaluate", "--task", "powder"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0, r.stderr
    assert 'pip install "lfd-landmarks[sim]"' in r.stderr
