"""Model files are untrusted input: loading never runs pickled code, foreign files get a clear error."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from lfd.learning.model import FORMAT, ModelFormatError, TaskModel
from helpers import entry_point, run_cli


class _Exploit:
    """Unpickling this would create ``marker`` (if code execution were allowed)."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (Path(self.marker),))


def _write_model_dir(tmp_path: Path, payload) -> Path:
    d = tmp_path / "model"
    d.mkdir()
    torch.save(payload, d / "model.pt")
    (d / "config.json").write_text(json.dumps({"format": FORMAT}))
    return d


def test_crafted_pickle_is_refused_without_running(tmp_path):
    marker = tmp_path / "pwned"
    d = _write_model_dir(tmp_path, {"tool": _Exploit(str(marker))})
    with pytest.raises(ModelFormatError, match="model.pt"):
        TaskModel.load(d)
    assert not marker.exists(), "the pickled payload was executed"


def test_not_a_model(tmp_path):
    d = tmp_path / "m"
    d.mkdir()
    (d / "model.pt").write_bytes(b"garbage")
    (d / "config.json").write_text("{}")
    with pytest.raises(ModelFormatError, match="not an lfd task model"):
        TaskModel.load(d)
    with pytest.raises(ModelFormatError, match="missing"):
        TaskModel.load(tmp_path / "absent")


def test_plan_cli_refuses_crafted_model(tmp_path, capsys):
    marker = tmp_path / "pwned"
    d = _write_model_dir(tmp_path, {"tool": _Exploit(str(marker))})
    cfg = json.loads((d / "config.json").read_text())
    r = run_cli(*entry_point("plan.py"), ["--model", d, "--out", tmp_path / "o"], capsys)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not marker.exists()
    assert cfg["format"] == FORMAT
