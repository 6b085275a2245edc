"""Interrupting train.py: Ctrl-C / SIGTERM leave a good checkpoint, --resume gives the same model.

The end-to-end test starts ``train.py`` as a subprocess on a small synthetic set, waits for the
first checkpoint, sends SIGINT, resumes (as a subprocess) and interrupts again with SIGTERM,
then resumes to the end in-process and compares with an uninterrupted run of the same seed.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from lfd.learning.checkpoint import (Interrupted, InterruptGuard, atomic_write_text, checkpoint_path, load_checkpoint,
                            temp_files)
from lfd.cli import UsageError
from helpers import synthetic_demo_dir

ROOT = Path(__file__).resolve().parent.parent
RESTARTS = 8


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    return synthetic_demo_dir(tmp_path_factory.mktemp("demos"), 4, 6, 3, (3, 5))


def _args(demos, out, *extra):
    return ["--task", "powder", "--demos", str(demos), "--out", str(out), "--restarts", str(RESTARTS),
            "--time-steps", "6", "--seed", "3", *extra]


@pytest.fixture(scope="module")
def reference(demos, tmp_path_factory):
    """An uninterrupted run (in-process)."""
    import train
    out = tmp_path_factory.mktemp("reference")
    assert train.main(_args(demos, out)) == 0
    return out


def _interrupt(argv, out: Path, sig: int, after: int):
    """Run train.py, send ``sig`` once the checkpoint holds ``after`` restarts; the finished process."""
    p = subprocess.Popen([sys.executable, "train.py", *argv], cwd=ROOT, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    rec = checkpoint_path(out)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and p.poll() is None:
        try:
            if json.loads(rec.read_text())["restarts_done"] >= after:
                break
        except (OSError, ValueError, KeyError):
            pass
        time.sleep(0.01)
    p.send_signal(sig)
    stdout, stderr = p.communicate(timeout=60)
    return p.returncode, stdout, stderr


def _check_interrupted(code, stderr, out, sig):
    assert code == 128 + sig, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in stderr, stderr
    assert f"interrupted by {signal.Signals(sig).name}" in lines[0]
    assert str(checkpoint_path(out)) in lines[0] and "--resume" in lines[0]
    progress = load_checkpoint(out)  # intact: the record's sha256 matches its tensor file
    assert 1 <= progress.restarts_done < RESTARTS
    pt = out / f"checkpoint_r{progress.restarts_done:03d}.pt"
    state = torch.load(pt, weights_only=True)
    assert set(state) == {"tool", "env", "mu", "sigma_inv", "log_trans", "alignment"}
    assert sorted(p.name for p in out.glob("checkpoint_r*.pt")) == [pt.name]
    assert temp_files(out) == []
    assert not (out / "model.pt").exists()
    return progress


def test_interrupt_and_resume_equal_an_uninterrupted_run(demos, reference, tmp_path):
    import train
    out = tmp_path / "run"
    code, _, err = _interrupt(_args(demos, out), out, signal.SIGINT, after=1)
    first = _check_interrupted(code, err, out, signal.SIGINT)

    code, stdout, err = _interrupt(_args(demos, out, "--resume"), out, signal.SIGTERM,
                                   after=first.restarts_done + 1)
    assert f"resuming from {checkpoint_path(out)}: {first.restarts_done} of {RESTARTS}" in stdout
    second = _check_interrupted(code, err, out, signal.SIGTERM)
    assert second.restart_losses[:first.restarts_done] == first.restart_losses
    assert 0 < first.elapsed_s < second.elapsed_s  # the fit's time goes on across sessions

    assert train.main(_args(demos, out, "--resume")) == 0
    got, want = (json.loads((d / "summary.json").read_text()) for d in (out, reference))
    assert got["resumed_restarts"] == second.restarts_done and want["resumed_restarts"] == 0
    # each session's TensorBoard run apart (a resumed restart's curve ran over its first attempt's)
    assert sorted(p.name for p in (out / "tensorboard").iterdir()) == ["session-0", "session-1", "session-2"]
    assert [p.name for p in (reference / "tensorboard").iterdir()] == ["session-0"]
    # the learning time counts every session (it was the last session's alone)
    assert got["learning_time_s"] > second.elapsed_s and got["timings"]["session_s"] < got["learning_time_s"]
    assert got["final_loss"] == pytest.approx(want["final_loss"], abs=1e-9)
    assert got["restart_losses"] == pytest.approx(want["restart_losses"], abs=1e-9)
    np.testing.assert_allclose(got["tool_point"], want["tool_point"], atol=1e-9)
    assert got["env_weights"].keys() == want["env_weights"].keys()
    np.testing.assert_allclose(list(got["env_weights"].values()), list(want["env_weights"].values()), atol=1e-9)
    a, b = (torch.load(d / "model.pt", weights_only=True) for d in (out, reference))
    for k in ("tool", "env", "mu", "sigma_inv"):
        torch.testing.assert_close(a[k], b[k], atol=1e-9, rtol=0)
    assert torch.equal(a["log_trans"], b["log_trans"])
    assert temp_files(out) == []


def test_resume_refuses_other_options_or_demos(demos, reference, tmp_path):
    import train
    out = tmp_path / "run"
    shutil.copytree(reference, out)  # its checkpoint holds all restarts
    with pytest.raises(UsageError, match=r"--resume: .*made with different options: restarts=8 there, 9 now"):
        train.main(_args(demos, out, "--resume", "--restarts", "9"))
    with pytest.raises(UsageError, match=r"different options: .*seed=3 there, 4 now"):
        train.main(_args(demos, out, "--resume", "--seed", "4"))
    other = tmp_path / "demos"
    shutil.copytree(demos, other)
    f = sorted(other.glob("*.npz"))[0]
    with np.load(f) as z:
        data = {k: z[k] for k in z.files}
    data["q"] = data["q"] + 1e-6  # still valid, but not the same demonstrations
    np.savez(f, **data)
    with pytest.raises(UsageError, match="made from different demonstrations"):
        train.main(_args(other, out, "--resume"))


def test_a_checkpoint_with_more_restarts_than_asked_for_is_refused_in_one_line(demos, reference, tmp_path):
    """A hand-edited checkpoint holding 16 restarts for a run of 8: the fit's refusal was a plain
    ValueError (a traceback from train.py) with a garbled sentence; now a user error that names
    both counts."""
    import train
    from lfd.cli import USER_ERRORS
    from lfd.learning.checkpoint import CheckpointError
    out = tmp_path / "run"
    shutil.copytree(reference, out)
    rec = checkpoint_path(out)
    data = json.loads(rec.read_text())
    for key in ("restart_losses", "loss_history", "em_iterations"):
        data[key] = data[key] * 2
    rec.write_text(json.dumps(data))
    with pytest.raises(CheckpointError, match=r"has 16 restarts done, more than the 8 asked for") as info:
        train.main(_args(demos, out, "--resume"))
    assert isinstance(info.value, USER_ERRORS())


# ----------------------------------------------------------------------------- the pieces
def test_atomic_write_interrupted_keeps_the_old_file(tmp_path, monkeypatch):
    target = tmp_path / "summary.json"
    atomic_write_text(target, "old\n")

    def boom(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "fsync", boom)
    with pytest.raises(KeyboardInterrupt):
        atomic_write_text(target, "new, half written")
    assert target.read_text() == "old\n"
    assert temp_files(tmp_path) == []


@pytest.mark.parametrize("sig,status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_guard_defers_signals_in_critical_sections(sig, status):
    reached = False
    with InterruptGuard() as guard:
        with pytest.raises(Interrupted) as info:
            with guard.critical():
                os.kill(os.getpid(), sig)
                time.sleep(0.05)  # the handler runs here, and must not raise yet
                reached = True
    assert reached and info.value.exit_status == status
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL  # handlers restored


def test_a_failure_inside_a_critical_section_is_not_hidden_by_a_signal_that_came_meanwhile():
    """Ctrl-C during a checkpoint write that then fails: the write's error is what surfaces (it was
    replaced by Interrupted, and the command said the checkpoint was saved)."""
    with InterruptGuard() as guard:
        with pytest.raises(OSError, match="disk full"):
            with guard.critical():
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.05)
                raise OSError("disk full")
        with guard.critical():  # the dropped signal is not raised later either
            pass


def test_checkpoint_round_trip_with_every_restart_dropped(tmp_path):
    from lfd.learning.checkpoint import FitProgress, save_checkpoint
    p = FitProgress(config={"seed": 0}, fingerprint="abc", restart_losses=(float("nan"),), loss_history=((),),
                    em_iterations=(0,), notes=("restart 0 dropped: non-finite loss",))
    save_checkpoint(tmp_path, p)
    q = load_checkpoint(tmp_path)
    assert q.best_state is None and q.best_restart is None and np.isnan(q.restart_losses[0])
    assert q.notes == p.notes and q.mismatch({"seed": 0}, "abc") is None
    assert "different options: seed=0 there, 1 now" in q.mismatch({"seed": 1}, "abc")


@pytest.mark.parametrize("best,value,fragment", [
    (5, 1.0, "best restart 5 is not one of its 1 restarts"),  # was an IndexError in the resumed fit
    (0, float("nan"), "holds NaN or infinite values"),  # was a Cholesky error blamed on the refit
])
def test_checkpoint_that_cannot_be_resumed_is_named(tmp_path, best, value, fragment):
    from lfd.learning.checkpoint import STATE_TENSORS, CheckpointError, FitProgress, save_checkpoint
    state = {k: torch.full((2,), value, dtype=torch.float64) for k in STATE_TENSORS}
    state["alignment"] = torch.zeros(2, dtype=torch.int64)
    p = FitProgress(config={"seed": 0}, fingerprint="abc", restart_losses=(-1.0,), loss_history=((-1.0,),),
                    em_iterations=(1,), notes=(), best_restart=best, best_state=state)
    save_checkpoint(tmp_path, p)
    with pytest.raises(CheckpointError, match="checkpoint") as info:
        load_checkpoint(tmp_path)
    assert fragment in str(info.value)


def test_checkpoint_log_trans_may_hold_minus_inf(tmp_path):
    """An impossible transition is -inf in log_trans: such a checkpoint resumes (the finiteness
    check once refused it and broke --resume)."""
    from lfd.learning.checkpoint import STATE_TENSORS, FitProgress, save_checkpoint
    state = {k: torch.zeros(2, dtype=torch.float64) for k in STATE_TENSORS}
    state["alignment"] = torch.zeros(2, dtype=torch.int64)
    state["log_trans"] = torch.tensor([0.0, float("-inf")], dtype=torch.float64)
    save_checkpoint(tmp_path, FitProgress(config={"seed": 0}, fingerprint="abc", restart_losses=(-1.0,),
                                          loss_history=((-1.0,),), em_iterations=(1,), notes=(),
                                          best_restart=0, best_state=state))
    assert load_checkpoint(tmp_path).best_state["log_trans"][1] == float("-inf")
