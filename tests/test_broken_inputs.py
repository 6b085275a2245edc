"""Broken input found by probing the entry points: each is refused with a message that names the
file or option, never a traceback, a hang, or a silent change of meaning.

(The demonstration format's common breakages are in ``test_demos_format.py``, crafted model
files in ``test_untrusted_model.py``; these are the rarer ones.)
"""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
import threading
import time
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from lfd.learning.demos import load_demos, save_demos

from lfd.learning.demoset import DemoFormatError
from lfd.learning.learn import FitConfig
from lfd.learning.model import ModelFormatError, TaskModel
from lfd.robot.robots import BAXTER_LEFT
from lfd.learning.tasks import POUR, POWDER, TaskSpec
from helpers import entry_point, rewrite_npz, run_cli, small_demoset

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def kin():
    from lfd.robot.kinematics import KinematicModel
    return KinematicModel.from_spec()


@pytest.fixture()
def good_dir(tmp_path):
    save_demos(tmp_path, small_demoset(2, 30, 0, ground_truth={"tool_point": [0, 0, 0.1]}))
    return tmp_path


def _cli_demos(path, *extra) -> subprocess.CompletedProcess:
    """``python -m lfd.learning.demos`` in a subprocess: for a case that could block (a FIFO), where a
    timeout must end the test; the others call the entry function in-process (``run_cli``)."""
    return subprocess.run([sys.executable, "-m", "lfd.learning.demos", str(path), *extra], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


def _one_line_exit_2(r, fragment: str) -> None:
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert fragment in r.stderr, r.stderr


# ----------------------------------------------------------------------------- task.json
@pytest.mark.parametrize("entry,fragment", [
    ({"time_steps": float("inf")}, "time_steps must be a whole number"),
    ({"time_steps": 6.9}, "time_steps must be a whole number"),  # was truncated to 6 silently
    ({"dt": float("inf")}, "dt must be a finite positive number"),
    ({"manual_tool_point": [0, 0, float("inf")]}, "manual_tool_point needs 3 finite numbers"),
    ({"name": {"a": 1}}, "name must be a name of letters, digits"),
    ({"name": "my task"}, "name must be a name of letters, digits"),  # no --task could name it
    ({"reference_landmark": ["bowl"]}, "reference_landmark must be a landmark's name"),
    ({"features": "orientation"}, "features must be one of paper, attitude"),
    ({"dt": 100.0}, "time step in seconds, at most 10; got 100.0"),  # a plan then stepped for hours
    ({"timesteps": 12}, "unknown task entries ['timesteps']"),  # was ignored: 24 steps learned
])
def test_task_json_entries_are_checked(good_dir, kin, entry, fragment):
    # json.dumps writes inf as Infinity, which Python's json reads back: a real file's content
    (good_dir / "task.json").write_text(json.dumps({**POWDER.to_dict(), **entry}))
    with pytest.raises(DemoFormatError, match="task.json") as info:
        load_demos(good_dir, kin=kin)
    assert fragment in str(info.value)


def test_retired_task_entry_is_ignored():
    """'tool_velocity', written by the code of a removed option, does not make a task.json unreadable."""
    assert TaskSpec.from_dict({**POUR.to_dict(), "tool_velocity": True}) == POUR


def test_task_json_dt_must_match_the_files(good_dir, kin):
    (good_dir / "task.json").write_text(json.dumps({**POWDER.to_dict(), "dt": 0.5}))  # files: 0.1
    with pytest.raises(DemoFormatError, match=r"task.json: dt=0.5 differs from the demonstrations' sampling"):
        load_demos(good_dir, kin=kin)


def test_task_spec_round_trip_and_numpy_numbers():
    for task in (POWDER, replace(POWDER, name="x", dt=np.float32(0.25), manual_tool_point=np.ones(3))):
        again = TaskSpec.from_dict(json.loads(json.dumps(task.to_dict())))
        assert again == task and type(again.dt) is float and type(again.time_steps) is int
    with pytest.raises(ValueError, match="a task needs 'name' and 'dt'"):
        TaskSpec.from_dict({"name": "x"})


# ----------------------------------------------------------------------------- ground_truth.json
@pytest.mark.parametrize("gt,fragment", [
    ("a string", "must be a JSON object"),
    ({"tool_point": [1, 2]}, "'tool_point' needs 3 finite numbers"),
    ({"tool_point": "abc"}, "'tool_point' needs 3 finite numbers"),
    ({"bowl_landmark": ["x"]}, "'bowl_landmark' must be a landmark's name"),
    ({"reference_points": [[0, 0, 0]]}, "'reference_points' must be an object"),
    ({"reference_points": {"aim": [0, 0]}}, "reference point 'aim' needs 3 finite numbers"),
])
def test_ground_truth_is_checked_before_any_fit(good_dir, kin, gt, fragment):
    """train.py reads it after the whole fit: a bad one used to crash there and lose the model."""
    (good_dir / "ground_truth.json").write_text(json.dumps(gt))
    with pytest.raises(DemoFormatError, match="ground_truth.json") as info:
        load_demos(good_dir, kin=kin)
    assert fragment in str(info.value)


# ----------------------------------------------------------------------------- .npz files
def _zip_with_member(path: Path, good: Path, name: str, data: bytes) -> None:
    """A copy of ``good`` whose member ``name`` holds ``data`` (not a .npy array)."""
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(path, "w") as dst:
        for item in src.infolist():
            dst.writestr(item.filename, data if item.filename == name else src.read(item.filename))


def test_member_that_is_not_an_array(good_dir, kin):
    target = good_dir / "demo_001.npz"
    _zip_with_member(good_dir / "tmp.zip", target, "q.npy", b"plain bytes, no .npy header")
    os.replace(good_dir / "tmp.zip", target)
    with pytest.raises(DemoFormatError, match=r"demo_001.npz: .*'q'"):
        load_demos(good_dir, kin=kin)


def test_damaged_member_is_not_blamed_on_pickle(good_dir, kin):
    target = good_dir / "demo_001.npz"
    with zipfile.ZipFile(target) as z:
        q = z.read("q.npy")
    _zip_with_member(good_dir / "tmp.zip", target, "q.npy", q[: len(q) // 2])  # header intact, data cut
    os.replace(good_dir / "tmp.zip", target)
    with pytest.raises(DemoFormatError, match="damaged .npz file") as info:
        load_demos(good_dir, kin=kin)
    assert "pickle" not in str(info.value)


def test_damaged_compressed_member_is_one_line(good_dir, kin):
    """A compressed archive whose deflate data is damaged was a zlib.error traceback."""
    target = good_dir / "demo_001.npz"
    with np.load(target) as z:
        arrays = {k: z[k] for k in z.files}
    np.savez_compressed(target, **arrays)
    with zipfile.ZipFile(target) as z:
        info = z.getinfo("q.npy")
    raw = bytearray(target.read_bytes())
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)  # the member's data
    for k in range(start + 60, start + 65):
        raw[k] ^= 0x5A
    target.write_bytes(bytes(raw))
    with pytest.raises(DemoFormatError, match=r"demo_001.npz: damaged .npz file"):
        load_demos(good_dir, kin=kin)


def test_member_whose_header_claims_a_huge_array_is_one_line(good_dir, kin):
    """A ``q.npy`` header claiming (1e11, 7) made numpy ask for 5 TiB: a MemoryError traceback."""
    import io

    target = good_dir / "demo_001.npz"
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False, "shape": (10 ** 11, 7)})
    _zip_with_member(good_dir / "tmp.zip", target, "q.npy", buf.getvalue() + bytes(64))  # magic, header, no data
    os.replace(good_dir / "tmp.zip", target)
    with pytest.raises(DemoFormatError, match=r"demo_001.npz: damaged .npz file"):
        load_demos(good_dir, kin=kin)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_fifo_named_npz_is_refused_without_blocking(good_dir):
    os.mkfifo(good_dir / "zz.npz")  # opening it would wait for a writer forever
    _one_line_exit_2(_cli_demos(good_dir), "not a regular file")


def test_broken_link_named_npz(good_dir, kin):
    (good_dir / "zz.npz").symlink_to(good_dir / "absent.npz")
    with pytest.raises(DemoFormatError, match=r"zz.npz: not a regular file"):
        load_demos(good_dir, kin=kin)


def test_byte_string_names_are_decoded(good_dir, kin):
    for f in sorted(good_dir.glob("*.npz")):
        rewrite_npz(f, joint_names=np.array([n.encode() for n in BAXTER_LEFT.joint_names]),
                    landmark_names=np.array([b"bowl", b"marker_1", b"marker_2"]))
    ds = load_demos(good_dir, kin=kin)
    assert ds.landmark_names == ("bowl", "marker_1", "marker_2")
    assert ds.joint_names == BAXTER_LEFT.joint_names


def test_empty_landmark_name_refused_before_any_fit(good_dir, kin):
    """A model refuses an empty landmark name, so the loader must too (not the end of a fit)."""
    for f in sorted(good_dir.glob("*.npz")):
        rewrite_npz(f, landmark_names=np.array(["bowl", "", "marker_2"]))
    with pytest.raises(DemoFormatError, match="'landmark_names' holds an empty name"):
        load_demos(good_dir, kin=kin)


def test_demos_cli_refuses_too_few_time_steps(good_dir, capsys):
    r = run_cli(*entry_point("python -m lfd.learning.demos"), [good_dir, "--time-steps", "0"], capsys)
    _one_line_exit_2(r, "--time-steps must be at least 2")


# ----------------------------------------------------------------------------- fit options
@pytest.mark.parametrize("kw,fragment", [
    ({"band": 10**23}, "FitConfig.band must be at most time_steps"),
    ({"band": 1.5}, "FitConfig.band must be a whole number >= 0, got 1.5"),
    ({"seed": -1}, "FitConfig.seed must be a whole number >= 0"),
    ({"seed": 10**23}, "FitConfig.seed must be a whole number in [0, 2**63)"),
    ({"offsets": (1, 2)}, "include 0 and 1"),
    ({"offsets": (0, 1, 1.5)}, "each of FitConfig.offsets must be a whole number >= 0, got 1.5"),
    ({"offsets": ()}, "FitConfig.offsets must be a sequence of whole numbers"),
])
def test_fit_options_fail_before_the_fit(kw, fragment):
    with pytest.raises(ValueError) as info:
        FitConfig(**kw)
    assert fragment in str(info.value)


def test_reference_landmark_missing_names_task_json():
    from lfd.robot.kinematics import KinematicModel
    from lfd.learning.learn import fit
    ds = small_demoset(2, 30, 0)
    ds = replace(ds, task=replace(ds.task, reference_landmark="vase"))
    with pytest.raises(ValueError, match=r"reference_landmark 'vase' \(task.json\), which is not among"):
        fit(ds, KinematicModel.from_spec(), FitConfig(env="bowl", restarts=1))


# ----------------------------------------------------------------------------- model folders
def _model_dir(tmp_path: Path) -> Path:
    """A small valid model folder (T = 4, one landmark), saved by TaskModel.save."""
    T, F = 4, 10
    model = TaskModel(torch.zeros(3, dtype=torch.float64), torch.ones(1, dtype=torch.float64),
                      torch.zeros(T, F, dtype=torch.float64),
                      torch.eye(F, dtype=torch.float64).repeat(T, 1, 1),
                      torch.log(torch.full((T, 3), 1 / 3, dtype=torch.float64)), ["bowl"], BAXTER_LEFT,
                      task=POWDER, covariance="block")
    out = tmp_path / "model"
    model.save(out)
    return out


def _break_tensor(d: Path, key: str, value) -> None:
    state = torch.load(d / "model.pt", weights_only=True)
    state[key] = value
    torch.save(state, d / "model.pt")


def _break_config(d: Path, **changes) -> None:
    cfg = json.loads((d / "config.json").read_text())
    cfg.update(changes)
    (d / "config.json").write_text(json.dumps(cfg))


BROKEN_MODELS = [
    ("mu-nan", lambda d: _break_tensor(d, "mu", torch.full((4, 10), float("nan"), dtype=torch.float64)),
     "mu holds NaN"),
    ("sigma-zero", lambda d: _break_tensor(d, "sigma_inv", torch.zeros(4, 10, 10, dtype=torch.float64)),
     "positive diagonal"),
    ("sigma-upper", lambda d: _break_tensor(d, "sigma_inv", torch.eye(10, dtype=torch.float64).repeat(4, 1, 1)
                                            + torch.triu(torch.full((10, 10), 0.3, dtype=torch.float64), 1)),
     "sigma_inv must be lower triangular"),  # loaded; its log det, read off the diagonal, was wrong
    ("names-repeated", lambda d: _break_config(d, all_landmark_names=["bowl", "bowl"]), "distinct non-empty strings"),
    # finite but extreme: loaded, then plan.py raised in the IK's SVD / the planner's Cholesky
    ("mu-huge", lambda d: _break_tensor(d, "mu", torch.full((4, 10), 1e200, dtype=torch.float64)),
     "mu holds values up to 1e+200"),
    ("sigma-tiny", lambda d: _break_tensor(d, "sigma_inv", 1e-200 * torch.eye(10, dtype=torch.float64).repeat(4, 1, 1)),
     "sigma_inv is too close to singular"),
    ("not-tensors", lambda d: _break_tensor(d, "tool", [0.0, 0.0, 0.0]), "must be real floating-point (dense) tensors"),
    ("complex", lambda d: _break_tensor(d, "tool", torch.zeros(3, dtype=torch.complex128)),
     "must be real floating-point (dense) tensors"),
    ("sparse", lambda d: _break_tensor(d, "tool", torch.zeros(3, dtype=torch.float64).to_sparse()),
     "must be real floating-point (dense) tensors"),  # was a NotImplementedError traceback in plan.py
    ("log-trans-positive", lambda d: _break_tensor(d, "log_trans", torch.ones(4, 3, dtype=torch.float64)),
     "log-probabilities"),
    ("log-trans-no-way", lambda d: _break_tensor(d, "log_trans", torch.tensor([[0.0, -math.inf, -math.inf]] * 4,
                                                                              dtype=torch.float64)),
     "no sequence of time steps"),  # loaded, then every plan was 'no_path'
    ("truncated", lambda d: (d / "model.pt").write_bytes((d / "model.pt").read_bytes()[:300]), "damaged or truncated"),
    ("pickled-module", lambda d: torch.save(torch.nn.Linear(2, 2), d / "model.pt"),
     "cannot be read as a tensor state dict: it holds Python objects, not only tensors (Unsupported global"),
    # torch's own text told the user that loading with weights_only=False 'will likely succeed'
    ("random-bytes", lambda d: (d / "model.pt").write_bytes(bytes(range(256)) * 16),
     "cannot be read as a tensor state dict: damaged, or not a file torch.save wrote (Unsupported operand"),
    ("env-not-one", lambda d: _break_tensor(d, "env", torch.full((1,), 0.5, dtype=torch.float64)), "sum to 1"),
    ("offsets-negative", lambda d: _break_config(d, offsets=[0, -1, 2]), "offsets must be distinct"),
    ("offsets-fraction", lambda d: _break_config(d, offsets=[0, 1.5, 2]), "offsets must be whole numbers"),
    ("logdet-nan", lambda d: _break_config(d, logdet_scale=float("nan")), "logdet_scale must be finite"),
    ("logdet-negative", lambda d: _break_config(d, logdet_scale=-5.0), "logdet_scale must be finite and positive"),
    ("tool-point-far", lambda d: _break_config(d, task={**POWDER.to_dict(), "manual_tool_point": [100.0, 0, 0]}),
     "is more than 2 m from the gripper"),
    ("names-null", lambda d: _break_config(d, landmark_names=[None], all_landmark_names=[None]),
     "distinct non-empty strings"),
    ("options-a-string", lambda d: _break_config(d, options="x"),  # was "dictionary update sequence element #0"
     "TaskModel.options must be a JSON object of how it was learned, got str 'x'"),
    ("names-a-string", lambda d: _break_config(d, landmark_names="bowl", all_landmark_names="bowl"),
     "landmark names must be a list of names, got the string 'bowl'"),  # listed ['b', 'o', 'w', 'l']
    ("robot-joints-a-string", lambda d: _break_config(d, robot={**BAXTER_LEFT.to_dict(), "joint_names": "left_s0"}),
     "joint_names must be a list of joint names, got the string 'left_s0'"),
    ("config-deep", lambda d: (d / "config.json").write_text("[" * 100_000 + "]" * 100_000), "not valid JSON"),
    ("task-inf", lambda d: _break_config(d, task={**POWDER.to_dict(), "time_steps": float("inf")}),
     "time_steps must be a whole number"),
]


@pytest.mark.parametrize("breaker,fragment", [b[1:] for b in BROKEN_MODELS], ids=[b[0] for b in BROKEN_MODELS])
def test_damaged_model_refused_on_load(tmp_path, breaker, fragment):
    d = _model_dir(tmp_path)
    assert TaskModel.load(d).time_steps == 4  # the folder is sound before it is broken
    breaker(d)
    with pytest.raises(ModelFormatError) as info:
        TaskModel.load(d)
    assert fragment in str(info.value)


def test_one_step_model_refused():
    with pytest.raises(ValueError, match="at least 2 time steps"):
        TaskModel(torch.zeros(3), torch.ones(1), torch.zeros(1, 10), torch.eye(10)[None],
                  torch.zeros(1, 3), ["bowl"], BAXTER_LEFT)


# ----------------------------------------------------------------------------- plan.py
def _plan(capsys, *args):
    """plan.py's entry function, in-process (``helpers.run_cli``)."""
    return run_cli(*entry_point("plan.py"), args, capsys)


@pytest.mark.parametrize("args,fragment", [
    (("--model", "m", "--scenario-seed", "-1"), "--scenario-seed must be in [0, 9223372036854775808)"),
    (("--model", "m", "--scenario-seed", str(2**63)), "--scenario-seed must be in [0, 9223372036854775808)"),
    (("--evaluate", "--task", "powder", "--seed", "-3"), f"--seed must be in [0, {2**63 // 100_003 - 1})"),
    (("--evaluate", "--task", "powder", "--seed", str(10**41)), "--seed must be in"),
    (("--evaluate", "--task", "powder", "--demos", "/nonexistent/demos"), "--demos /nonexistent/demos: no such folder"),
    (("--evaluate", "--task", "powder", "--scenarios", "100004"), "--scenarios must be at most 100003"),  # sets overlapped
    (("--evaluate", "--task", "powder", "--scenarios", "0"), "--scenarios must be at least 1, got 0"),
    (("--evaluate", "--task", "powder", "--workers", "0"), "--workers must be at least 1, got 0"),
])
def test_plan_cli_checks_seeds_and_folders_first(args, fragment, capsys):
    _one_line_exit_2(_plan(capsys, *args), fragment)


def test_plan_cli_gui_without_a_display_is_one_line(capsys, monkeypatch):
    """``plan.py --gui`` on Linux without DISPLAY was a RuntimeError traceback (after the model
    loaded) that pointed to a --snapshot option plan.py does not have."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    _one_line_exit_2(_plan(capsys, "--model", "m", "--gui"), "--gui: the PyBullet GUI needs a display (DISPLAY is not set)")


class _FakeX:
    """A listener where an X server would be: ``answer`` bytes sent back after the client's
    connection set-up (``b""``: it accepts and never answers, like a hung server; None: it
    closes the connection, as ssh's X forwarding does without the cookie)."""

    def __init__(self, family, address, answer: bytes | None):
        self.sock = socket.socket(family, socket.SOCK_STREAM)
        self.sock.bind(address)
        self.sock.listen(4)
        self.answer, self.received, self.conns = answer, [], []
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:  # closed
                return
            self.conns.append(conn)
            self.received.append(conn.recv(12))
            if self.answer is None:  # as ssh's X forwarding does with a set-up without its cookie
                conn.close()
            elif self.answer:
                conn.sendall(self.answer)

    def close(self):
        for c in self.conns:
            c.close()
        self.sock.shutdown(socket.SHUT_RDWR)  # (wakes the accept; a bare close leaves it listening)
        self.sock.close()


def _fake_x(family, answer: bytes | None):
    """A ``_FakeX`` on a free display number; ``(server, DISPLAY)``."""
    for n in range(4242, 4342):
        address = ("127.0.0.1", 6000 + n) if family == socket.AF_INET else f"\0/tmp/.X11-unix/X{n}"
        try:
            server = _FakeX(family, address, answer)
        except OSError:
            continue
        return server, (f"127.0.0.1:{n}.0" if family == socket.AF_INET else f":{n}")
    pytest.skip("no free display number")


@pytest.mark.parametrize("family", [socket.AF_INET, socket.AF_UNIX])
def test_gui_with_an_x_server_that_does_not_answer_is_refused_in_seconds(family, capsys, monkeypatch):
    """``plan.py --gui`` with a DISPLAY whose X server does not answer waited for ever inside
    PyBullet's connect; one that refuses the connection made PyBullet exit the process (status 1,
    its own 'cannot connect to X server'). Both are one line and status 2 now, before the model
    loads; a server that answers the X11 set-up at all (here: 'Failed', as to a client without
    its cookie) is left to PyBullet."""
    import sim.world
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.setattr(sim.world, "X_ANSWER_S", 0.3)
    sim.world._x_problem.cache_clear()
    mute, display = _fake_x(family, b"")
    try:
        monkeypatch.setenv("DISPLAY", display)
        tic = time.perf_counter()
        _one_line_exit_2(_plan(capsys, "--model", "m", "--gui"),
                         f"--gui: the X server of DISPLAY={display} does not answer (nothing in 0.3 s)")
        assert time.perf_counter() - tic < 5.0
        assert mute.received and mute.received[0][:1] == b"l" and len(mute.received[0]) == 12  # the X11 set-up
    finally:
        mute.close()
    sim.world._x_problem.cache_clear()
    assert "cannot be reached" in sim.world.no_display()  # nobody listens there now
    for answer in (b"\0", None):  # 'Failed' (no cookie), or closed at once (ssh -X without the cookie)
        sim.world._x_problem.cache_clear()
        server, display = _fake_x(family, answer)
        try:
            monkeypatch.setenv("DISPLAY", display)
            assert sim.world.no_display() == "", answer
            assert sim.world.no_display() == "" and len(server.received) == 1  # probed once per display
        finally:
            server.close()
    for other in ("weird", "host/x:0", "tcp/h:99999999"):  # forms the probe does not know: left to PyBullet
        monkeypatch.setenv("DISPLAY", other)
        assert sim.world.no_display() == ""


def test_evaluation_whose_training_fails_exits_2_without_a_traceback(tmp_path, capsys):
    """A variant trained on demand from broken demonstrations: one line says which variant failed
    and the training's reason; nothing is simulated and no model folder is left."""
    demos = tmp_path / "demos"
    save_demos(demos, small_demoset(2, 30, 0))
    rewrite_npz(demos / "demo_001.npz", dt=np.float64(-1.0))
    r = _plan(capsys, "--evaluate", "--task", "powder", "--scenarios", "1", "--workers", "1",
              "--variants", "learned+learned", "--models", str(tmp_path / "models"), "--demos", str(demos),
              "--out", str(tmp_path / "eval"))
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    lines = [line for line in r.stderr.strip().splitlines() if not line.startswith("[evaluate]")]
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("plan.py: error: training the learned+learned model (learn-learn) failed with "
                               "exit status 2: ")
    assert "must be positive" in lines[0]  # the training's own reason
    assert not (tmp_path / "eval" / "runs.jsonl").exists()
    assert not (tmp_path / "models" / "learn-learn").exists()
