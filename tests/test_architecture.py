"""The import rules of docs/ARCHITECTURE.md: no cycles among lfd's and sim's modules (lazy
imports included), and the errors a user can fix share one base the command line catches."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _imports() -> dict[str, set[str]]:
    """Module -> the lfd/sim modules it imports anywhere in its file (packages themselves left out)."""
    graph: dict[str, set[str]] = {}
    for pkg in ("lfd", "sim"):
        for path in (ROOT / pkg).rglob("*.py"):
            if path.stem == "__init__":
                continue
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            deps: set[str] = set()
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                    deps.add(node.module)
                    deps.update(f"{node.module}.{a.name}" for a in node.names)  # from sim import layout
                elif isinstance(node, ast.Import):
                    deps.update(a.name for a in node.names)
            graph[name] = deps
    return {m: {d for d in deps if d in graph and d != m} for m, deps in graph.items()}


def test_no_import_cycles():
    graph = _imports()
    assert "lfd.planning.planner" in graph["lfd.planning.task_planner"]  # the scan sees imports at all
    state: dict[str, int] = {}
    cycles = []

    def visit(m, stack):
        state[m] = 1
        for d in sorted(graph[m]):
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d):] + [d])
            elif d not in state:
                visit(d, stack + [d])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    assert cycles == []


def test_user_errors_share_one_base():
    from lfd.cli import USER_ERRORS, UsageError
    from lfd.learning.demoset import DemoFormatError
    from lfd.errors import UserInputError
    from lfd.robot.kinematics import KinematicsError
    from lfd.learning.model import ModelFormatError

    for cls in (UsageError, DemoFormatError, KinematicsError, ModelFormatError):
        assert issubclass(cls, UserInputError) and issubclass(cls, ValueError)
        assert isinstance(cls("x"), USER_ERRORS())
    assert not isinstance(RuntimeError("x"), USER_ERRORS())
