"""train.py and plan.py on bad input: one line on stderr, its own message, exit status 2.

Every case calls the command's entry function in this process as its script does
(``lfd.cli.run_main`` of ``lfd.train_cli.main`` / ``sim.plan_cli.main`` with the argument list),
capturing stdout and stderr. Numerical trouble (restarts whose loss becomes NaN) is tested by
poisoning the EM loss. Then the command-line conventions themselves: help texts with defaults,
the landmark vocabulary, ``--device``, no output folder left by a failed run, ``--quiet``,
TensorBoard missing, ``--model`` given a file (``setup.py``'s console scripts: test_packaging.py).
"""

from __future__ import annotations

import json
import math
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lfd.learning.checkpoint import FitProgress, save_checkpoint
from lfd.learning.demos import save_demonstration, save_demos
from lfd.learning.demoset import DemoSet
from lfd.robot.robots import BAXTER_LEFT, RobotSpec
from lfd.learning.tasks import POWDER
from helpers import entry_point, rewrite_npz, run_cli, small_demoset, synthetic_demo_dir

ROOT = Path(__file__).resolve().parent.parent
NAMES = ("bowl", "marker_1", "marker_2")
RUN = ["--restarts", "1", "--time-steps", "4"]  # where a run could start, it would be short


def _demoset(n=2, samples=30, seed=0) -> DemoSet:
    return small_demoset(n, samples, seed)


_rewrite = rewrite_npz


def _not_rigid():
    T = np.tile(np.eye(4), (3, 1, 1))
    T[1, :3, :3] *= 1.5
    return T


def _demos(**changes):
    """A setup: a demonstration folder with ``demo_001.npz`` changed; returns train.py's arguments."""
    def setup(d: Path, good: Path):
        shutil.copytree(good, d / "demos")
        if changes:
            _rewrite(d / "demos" / "demo_001.npz", **changes)
        return ["train.py", "--task", "powder", "--demos", str(d / "demos"), "--out", str(d / "out"), *RUN]
    return setup


def _unknown_joint(d, good):
    ds = _demoset()
    bad = [*BAXTER_LEFT.joint_names[:-1], "left_w9"]
    (d / "demos").mkdir()
    for i, demo in enumerate(ds.demos):
        save_demonstration(d / "demos" / f"d{i}.npz", demo, bad, NAMES, BAXTER_LEFT)
    return ["train.py", "--task", "powder", "--demos", str(d / "demos"), "--out", str(d / "out"), *RUN]


def _not_a_zip(d, good):
    shutil.copytree(good, d / "demos")
    (d / "demos" / "demo_001.npz").write_bytes(b"this is not a zip file")
    return ["train.py", "--task", "powder", "--demos", str(d / "demos"), "--out", str(d / "out"), *RUN]


def _empty(d, good):
    (d / "demos").mkdir()
    return ["train.py", "--task", "powder", "--demos", str(d / "demos"), "--out", str(d / "out"), *RUN]


def _bad_task_json(d, good):
    shutil.copytree(good, d / "demos")
    (d / "demos" / "task.json").write_text("{not json")
    return ["train.py", "--task", "powder", "--demos", str(d / "demos"), "--out", str(d / "out"), *RUN]


def _no_task_json(task: str, *extra: str):
    def setup(d, good):
        shutil.copytree(good, d / "demos")
        (d / "demos" / "task.json").unlink()
        return ["train.py", "--task", task, "--demos", str(d / "demos"), "--out", str(d / "out"), *RUN, *extra]
    return setup


def _task_json_subsample(d, good):
    shutil.copytree(good, d / "demos")
    task = json.loads((d / "demos" / "task.json").read_text())
    (d / "demos" / "task.json").write_text(json.dumps({**task, "subsample": 1000}))
    return ["train.py", "--task", "powder", "--demos", str(d / "demos"), "--out", str(d / "out"), *RUN]


def _train(*extra, out=None):
    """A setup: valid demonstrations, train.py with ``extra`` arguments."""
    def setup(d: Path, good: Path):
        o = out(d) if out else d / "out"
        return ["train.py", "--task", "powder", "--demos", str(good), "--out", str(o), *RUN, *extra]
    return setup


def _out_is_file(d):
    (d / "f").write_text("x")
    return d / "f"


def _out_under_file(d):
    (d / "f").write_text("x")
    return d / "f" / "sub"


def _damaged_checkpoint(d, good):
    save_checkpoint(d, FitProgress(config={}, fingerprint="x", restart_losses=(float("nan"),),
                                   loss_history=((),), em_iterations=(0,), notes=("restart 0 dropped",)))
    (d / "checkpoint_r001.pt").write_bytes(b"garbage")
    return ["train.py", "--task", "powder", "--demos", str(good), "--out", str(d), *RUN, "--resume"]


def _plan(*args, model=None):
    def setup(d: Path, good: Path):
        extra = ["--model", str(model(d))] if model else []
        return ["plan.py", *extra, *args]
    return setup


def _model(d: Path, names=("bowl", "cup"), robot=BAXTER_LEFT, task=POWDER, where="m") -> Path:
    """A small valid model (T=4) that keeps the landmarks ``names``, saved into ``d / where``."""
    import torch
    from lfd.learning.model import TaskModel
    T, F, z = 4, len(robot.joint_names) + 3, len(names)
    m = TaskModel(torch.zeros(3, dtype=torch.float64), torch.full((z,), 1.0 / z, dtype=torch.float64),
                  torch.zeros(T, F, dtype=torch.float64), torch.eye(F, dtype=torch.float64).repeat(T, 1, 1),
                  torch.full((T, 3), math.log(1 / 3), dtype=torch.float64), names, robot, task=task,
                  covariance="block")
    m.save(d / where)
    return d / where


def _other_robot(d):
    arm = RobotSpec(name="other_arm", urdf=BAXTER_LEFT.urdf, end_link="tool0",
                    joint_names=tuple(f"joint_{i}" for i in range(6)))
    return _model(d, names=("bowl",), robot=arm)


def _missing_urdf(d):
    return _model(d, names=("bowl",), robot=replace(BAXTER_LEFT, urdf=str(d / "gone" / "baxter.urdf")))


def _evaluate_models(task: str, model_task=POWDER, names=("bowl",)):
    """plan.py --evaluate --task ``task`` on a --models folder whose learned+learned model was
    trained on ``model_task`` with ``names``."""
    def setup(d: Path, good: Path):
        _model(d, names=names, task=model_task, where="models/learn-learn")
        return ["plan.py", "--evaluate", "--task", task, "--models", str(d / "models"), "--variants",
                "learned+learned", "--scenarios", "1", "--workers", "1", "--out", str(d / "eval")]
    return setup


def _incomplete_model(d):
    (d / "m").mkdir()
    (d / "m" / "config.json").write_text(json.dumps({"format": "lfd-task-model/1", "task": {"name": "powder"}}))
    return d / "m"


def _evaluate_demos_without_task_json(d: Path, good: Path):
    shutil.copytree(good, d / "demos")
    (d / "demos" / "task.json").unlink()
    return ["plan.py", "--evaluate", "--task", "powder", "--models", str(d / "models"), "--demos", str(d / "demos"),
            "--variants", "learned+learned", "--scenarios", "1", "--workers", "1", "--out", str(d / "eval")]


def _evaluate_demo_file_without_task_json(d: Path, good: Path):
    argv = _evaluate_demos_without_task_json(d, good)
    argv[argv.index("--demos") + 1] = str(d / "demos" / "demo_000.npz")  # one file: its folder's task.json
    return argv


def _evaluate_summary(text: str):
    """plan.py --evaluate on a --models folder whose trained model's summary.json holds ``text``."""
    def setup(d: Path, good: Path):
        argv = _evaluate_models("powder")(d, good)
        (d / "models" / "learn-learn" / "summary.json").write_text(text)
        return argv
    return setup


# (id, setup(tmp_dir, good_demos_dir) -> argv, distinctive fragment of the one stderr line)
CASES = [
    # broken demonstration files, through train.py --demos
    ("missing-key", _demos(q=None), r"missing key(s) ['q']"),
    ("nan", _demos(q=np.full((30, 7), np.nan)), "'q' holds NaN"),
    ("wrong-shape", _demos(q=np.zeros((30, 6))), "'q' has 6 columns"),
    ("too-short", _demos(q=np.zeros((3, 7))), "only 3 samples, fewer than the 4 time steps"),
    ("out-of-limits", _demos(q=np.full((30, 7), 2.9)), "outside its limits"),
    ("not-rigid", _demos(landmark_poses=_not_rigid()), "'marker_1' pose is not a rigid transform"),
    ("dt-zero", _demos(dt=np.float64(0.0)), "'dt' (sampling interval, seconds) must be positive and at most 1, got 0.0"),
    ("dt-milliseconds", _demos(dt=np.float64(20.0)), "got 20.0 (milliseconds given as seconds?)"),
    ("landmark-names", _demos(landmark_names=np.array(["bowl", "marker_1", "vase"])),
     "landmark_names ['bowl', 'marker_1', 'vase'] (Z=3) differ"),
    ("pickled-object-array", _demos(landmark_names=np.array(["bowl", 1, None], dtype=object)),
     "cannot read without pickle"),
    ("unknown-joint", _unknown_joint, "unknown joint name(s) ['left_w9']"),
    ("not-a-zip", _not_a_zip, "not a readable .npz file"),
    ("empty-folder", _empty, "no demonstration files (*.npz)"),
    ("bad-task-json", _bad_task_json, "not a valid task definition"),
    ("no-such-folder", lambda d, g: ["train.py", "--task", "powder", "--demos", str(d / "absent"), "--out",
                                     str(d / "out"), *RUN], "no such demonstration folder"),
    # arguments of train.py
    ("own-task-without-demos", lambda d, g: ["train.py", "--task", "stir"], "--task stir: give --demos DIR"),
    ("out-empty", lambda d, g: ["train.py", "--task", "powder", "--demos", str(g), "--out", ""],
     "argument --out: an empty path"),  # the model, checkpoints and logs went into the current folder
    ("bad-tool", _train("--tool", "spoon"), "argument --tool: invalid choice: 'spoon'"),
    ("bad-covariance", _train("--covariance", "diag"), "argument --covariance: invalid choice: 'diag'"),
    ("restarts-0", _train("--restarts", "0"), "--restarts must be at least 1, got 0"),
    ("workers-0", _train("--workers", "0"), "--workers must be at least 1, got 0"),
    ("time-steps-1", _train("--time-steps", "1"), "--time-steps must be at least 2, got 1"),
    ("offsets-too-far", _train("--time-steps", "8", "--offsets", "0", "1", "30"),
     "FitConfig.offsets: 30 is larger than the largest permitted, max(2, time_steps // 2) = 4"),
    ("band-word", _train("--band", "wide"), "--band must be a whole number of steps or 'none', got 'wide'"),
    ("band-negative", _train("--band", "-2"), "FitConfig.band must be a whole number >= 0, got -2"),
    ("subsample-0", _train("--subsample", "0"), "--subsample must be at least 1, got 0"),
    ("subsample-step", _train("--subsample", "101"), "--subsample 101: a time step of 10.1 s, more than a task's 10 s"),
    ("subsample-step-task-json", _task_json_subsample,  # named --subsample, which was not given
     "task.json: not a valid task definition: TaskSpec.subsample 1000: a time step of 100 s learned, more than 10"),
    ("built-in-task-no-task-json", _no_task_json("powder"),
     "has no task.json; the built-in task 'powder' learns with its own settings from one"),
    ("manual-no-task-json", _no_task_json("scoop", "--tool", "manual", "--env", "manual"),
     "--tool, --env manual need(s) the hand-picked tool point and reference landmark of a task.json"),
    ("subsample-word", _train("--subsample", "half"), "argument --subsample: invalid int value: 'half'"),
    ("floor-zero", _train("--floor-task", "0"),
     "FitConfig.floor_joint, floor_task and floor_attitude must be positive standard deviations, got 0.001, 0.0, 0.01"),
    ("floor-huge", _train("--floor-joint", "1e308"),  # was a Cholesky error in every restart
     "FitConfig.floor_joint must be at most 6.283, wider than the feature's whole range"),
    ("floor-attitude-paper", _train("--floor-attitude", "0.02", "--features", "paper"),
     "--floor-attitude applies to the attitude features"),
    ("bad-features", _train("--features", "orientation"), "argument --features: invalid choice: 'orientation'"),
    ("out-is-file", _train(out=_out_is_file), "exists and is not a folder"),
    ("out-under-a-file", _train(out=_out_under_file), "cannot create this folder (Not a directory)"),
    ("device-cuda", _train("--device", "cuda"), "--device cuda: torch.cuda.is_available() is False"),
    ("device-meta", _train("--device", "meta"), "--device meta: the meta device holds no data"),
    ("device-hpu", _train("--device", "hpu"), "--device hpu: this machine's torch cannot use it"),
    ("resume-no-checkpoint", _train("--resume"), "--resume: ", ),
    ("resume-damaged-checkpoint", _damaged_checkpoint, "damaged (sha256 differs"),
    # plan.py
    ("plan-model-missing", _plan(model=lambda d: d / "absent"), "absent: no such folder"),  # said "no config.json"
    ("plan-model-empty-folder", _plan(model=lambda d: d), "no config.json (train one with train.py)"),
    ("plan-model-incomplete", _plan(model=_incomplete_model), "not an lfd task model (missing model.pt)"),
    ("plan-evaluate-no-task", _plan("--evaluate"), "--evaluate needs --task"),
    ("plan-roadmap-size", _plan("--roadmap-size", "5", model=lambda d: d), "--roadmap-size must be in [10, 100000], got 5"),
    ("plan-roadmap-huge", _plan("--roadmap-size", str(10**14), model=lambda d: d),
     "--roadmap-size must be in [10, 100000], got 100000000000000"),  # filled the memory
    ("seed-negative", _train("--seed", "-1"), "--seed must be in [0, 2**63), got -1"),  # a numpy traceback
    ("plan-move-bowl-once", _plan("--move-bowl", model=lambda d: d), "--move-bowl is not for one plan"),
    # an option of the other mode was accepted and ignored
    ("plan-once-with-sweep-options", _plan("--scenarios", "5", "--workers", "1", model=lambda d: d),
     "--scenarios, --workers are not for one plan (--model)"),
    ("plan-evaluate-with-model", _plan("--evaluate", "--task", "powder", "--execute", model=lambda d: d),
     "--model, --execute are not for --evaluate"),
    # plan.py with a model that cannot plan in the simulated scenarios: refused before any simulation
    ("plan-model-other-landmarks", _plan(model=_model),
     "needs landmark(s) ['cup'], which the powder scenarios do not sense; they provide ['bowl', 'marker_1', "),
    ("plan-model-other-robot", _plan(model=_other_robot), "learned for robot 'other_arm' (end link 'tool0'"),
    ("plan-model-missing-urdf", _plan(model=_missing_urdf),
     "its config.json names the robot description"),  # named the URDF alone, not where it came from
    ("plan-model-no-task", _plan(model=lambda d: _model(d, names=("bowl",), task=None)),
     "the model names no task (its demonstrations had no task.json)"),  # was planned as powder at 0.1 s
    ("plan-model-not-of-task", _plan("--task", "pour", model=lambda d: _model(d, names=("bowl",))),
     "a model of task 'powder', not 'pour'"),  # --task was ignored with --model
    ("plan-model-other-task", _plan(model=lambda d: _model(d, names=("bowl",), task=replace(POWDER, name="stir"))),
     "a model of task 'stir'; the simulator has scenarios of powder, pour only"),
    ("plan-evaluate-other-landmarks", _evaluate_models("powder", names=("bowl", "cup")),
     "learn-learn: the model needs landmark(s) ['cup']"),
    ("plan-evaluate-other-task", _evaluate_models("pour"), "learn-learn: a model of task 'powder', not 'pour'"),
    ("plan-evaluate-demos-no-task-json", _evaluate_demos_without_task_json,
     "has no task.json, which gives the model its task and time step"),  # was trained, run at 0.1 s a step
    ("plan-evaluate-demo-file-no-task-json", _evaluate_demo_file_without_task_json,
     "demo_000.npz's folder"),  # was trained: the check looked at folders only
    ("plan-evaluate-summary-truncated", _evaluate_summary('{"time_st'), "summary.json: not valid JSON"),
    ("plan-evaluate-summary-list", _evaluate_summary("[]"), "a training summary is a JSON object, got list"),
]
NO_OUTPUT = {  # refused before anything was simulated or written
    "plan-model-other-landmarks": "runs", "plan-model-other-robot": "runs", "plan-model-other-task": "runs",
    "plan-evaluate-other-landmarks": "eval", "plan-evaluate-other-task": "eval",
    "plan-evaluate-demos-no-task-json": "models/learn-learn",
    "plan-evaluate-demo-file-no-task-json": "models/learn-learn"}
FRAGMENT_EXTRA = {"resume-no-checkpoint": "no checkpoint to resume from"}


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    """A valid demonstration folder."""
    d = tmp_path_factory.mktemp("good")
    save_demos(d, _demoset())
    return d


def test_cases_are_distinct():
    assert len(CASES) >= 20
    assert len({c[0] for c in CASES}) == len({c[2] for c in CASES}) == len(CASES)


@pytest.mark.parametrize("cid,setup,fragment", CASES, ids=[c[0] for c in CASES])
def test_bad_input_one_line_exit_2(good, tmp_path, monkeypatch, capsys, cid, setup, fragment):
    monkeypatch.chdir(tmp_path)  # a default output folder would be made here, never in the repository
    command, *argv = setup(tmp_path, good)
    r = run_cli(*entry_point(command), argv, capsys)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    assert len(lines) == 1, r.stderr
    assert lines[0].split(":")[0] in ("train.py", "plan.py")
    assert ": error: " in lines[0]
    assert fragment in lines[0], lines[0]
    assert FRAGMENT_EXTRA.get(cid, "") in lines[0]
    if cid in NO_OUTPUT:
        assert not (tmp_path / NO_OUTPUT[cid]).exists()
    if cid == "out-empty":  # the current folder
        assert not any(tmp_path.iterdir()), sorted(tmp_path.iterdir())
    elif command == "train.py" and "--out" in argv and cid not in ("out-is-file", "out-under-a-file"):
        out = Path(argv[argv.index("--out") + 1])  # a failed run leaves no folder it created
        assert not out.exists() or cid == "resume-damaged-checkpoint", sorted(out.iterdir())


# ----------------------------------------------------------------------------- numerical trouble
@pytest.fixture(scope="module")
def synth_dir(tmp_path_factory):
    return synthetic_demo_dir(tmp_path_factory.mktemp("synth"), 3, 5, 2, (3, 4))


def _poison(monkeypatch, first_calls: float):
    """Make ``EMFitter.total_loss`` NaN for its first ``first_calls`` calls."""
    from lfd.learning.em import EMFitter
    original, calls = EMFitter.total_loss, {"n": 0}

    def total_loss(self, *a):
        calls["n"] += 1
        return math.nan if calls["n"] <= first_calls else original(self, *a)

    monkeypatch.setattr(EMFitter, "total_loss", total_loss)


def _train_main(argv):
    import train
    from lfd.cli import run_main
    with pytest.raises(SystemExit) as info:
        run_main(train.main, argv, prog="train.py")
    return info.value.code


def test_nan_restart_is_dropped_with_a_warning(synth_dir, tmp_path, monkeypatch, capsys):
    _poison(monkeypatch, first_calls=1)  # restart 0 turns NaN at its first EM iteration
    out = tmp_path / "out"
    code = _train_main(["--task", "powder", "--demos", str(synth_dir), "--out", str(out),
                        "--restarts", "2", "--time-steps", "5"])
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["restart_losses"][0] is None and math.isfinite(summary["restart_losses"][1])
    assert summary["best_restart"] == 1 and math.isfinite(summary["final_loss"])
    assert any("restart 0 dropped: non-finite loss" in w for w in summary["warnings"])
    eff = summary["effective_demos_per_step"]  # one per step, each between 0 and the demonstrations
    assert len(eff) == summary["time_steps"] and all(0 <= x <= summary["n_demos"] + 1e-9 for x in eff)
    assert "warning: restart 0 dropped" in capsys.readouterr().out
    import torch
    state = torch.load(out / "model.pt", weights_only=True)
    assert all(bool(torch.isfinite(v).all()) for k, v in state.items() if k != "log_trans")
    assert not bool(torch.isnan(state["log_trans"]).any())


def test_all_restarts_failing_stops_without_a_model(synth_dir, tmp_path, monkeypatch, capsys):
    _poison(monkeypatch, first_calls=math.inf)
    out = tmp_path / "out"
    code = _train_main(["--task", "powder", "--demos", str(synth_dir), "--out", str(out),
                        "--restarts", "2", "--time-steps", "5"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("train.py: error: every one of the 2 restarts failed")
    assert not out.exists()  # the folder it made (checkpoints, TensorBoard logs) is gone with the run


def test_the_task_json_stride_is_the_default_and_subsample_overrides_it(synth_dir, tmp_path, capsys):
    from lfd.learning.tasks import TaskSpec
    demos = tmp_path / "demos"
    shutil.copytree(synth_dir, demos)
    task = TaskSpec.load(demos / "task.json")
    replace(task, subsample=2).save(demos / "task.json")
    for extra, stride in (([], 2), (["--subsample", "1"], 1)):
        out = tmp_path / f"out{stride}"
        assert _train_main(["--task", "powder", "--demos", str(demos), "--out", str(out),
                            "--restarts", "1", "--time-steps", "5", *extra]) == 0
        summary = json.loads((out / "summary.json").read_text())
        config = json.loads((out / "config.json").read_text())
        n_raw = sum(len(np.load(f)["q"]) for f in sorted(demos.glob("*.npz")))
        n_used = sum(len(np.load(f)["q"][::stride]) for f in sorted(demos.glob("*.npz")))
        assert summary["subsample"] == stride and summary["n_observations"] == n_used
        assert summary["dt"] == pytest.approx(stride * task.dt) == config["task"]["dt"]
        assert config["task"]["subsample"] == 1 and config["options"]["subsample"] == stride
    assert f"(1 in 2 of {n_raw}) at dt {2 * task.dt:g} s" in capsys.readouterr().out


def test_the_task_json_restarts_are_the_default_and_restarts_overrides_them(synth_dir, tmp_path):
    """A task.json's ``restarts`` is what train.py runs unless ``--restarts`` says otherwise;
    without one, FitConfig's default."""
    from lfd.learning.learn import FitConfig
    from lfd.learning.tasks import TaskSpec
    demos = tmp_path / "demos"
    shutil.copytree(synth_dir, demos)
    task = TaskSpec.load(demos / "task.json")
    assert task.restarts is None
    for restarts, extra, want in ((3, [], 3), (3, ["--restarts", "2"], 2), (None, [], FitConfig().restarts)):
        replace(task, restarts=restarts).save(demos / "task.json")
        out = tmp_path / f"out{restarts}{len(extra)}"
        assert _train_main(["--task", "powder", "--demos", str(demos), "--out", str(out), "--time-steps", "5",
                            *extra]) == 0
        summary = json.loads((out / "summary.json").read_text())
        assert summary["restarts"] == want and len(summary["restart_losses"]) == want


def test_max_dwell_option_reaches_the_fit_and_the_summary(synth_dir, tmp_path, capsys):
    """``--max-dwell`` sets ``FitConfig.max_dwell`` (``none``: unlimited, the paper's DTW), the
    summary records it, and a value below 1 is a usage error naming the option."""
    for value, want in (([], 2.0), (["--max-dwell", "none"], None), (["--max-dwell", "3"], 3.0)):
        out = tmp_path / f"out{want}"
        assert _train_main(["--task", "powder", "--demos", str(synth_dir), "--out", str(out),
                            "--restarts", "1", "--time-steps", "5", *value]) == 0
        assert json.loads((out / "summary.json").read_text())["max_dwell"] == want
    capsys.readouterr()
    for bad, fragment in (("0.5", "FitConfig.max_dwell must be at least 1"), ("two", "--max-dwell must be a number")):
        assert _train_main(["--task", "powder", "--demos", str(synth_dir), "--out", str(tmp_path / "bad"),
                            "--restarts", "1", "--time-steps", "5", "--max-dwell", bad]) == 2
        assert fragment in capsys.readouterr().err


# ----------------------------------------------------------------------------- command-line conventions
def _parsers():
    from lfd import train_cli
    from sim import plan_cli
    return {"train.py": train_cli.build_parser("train.py"), "plan.py": plan_cli.build_parser("plan.py")}


@pytest.mark.parametrize("command", ["train.py", "plan.py"])
def test_every_option_has_help_with_its_default(command):
    parser = _parsers()[command]
    formatter = parser._get_formatter()
    options = [a for a in parser._actions if a.option_strings and a.dest != "help"]
    assert len(options) >= 10
    for action in options:
        assert action.help and len(action.help) > 10, action.option_strings
        shown = formatter._get_help_string(action)
        assert action.required or "default" in shown, (action.option_strings, shown)
    text = parser.format_help()
    for fragment in {"train.py": ["(default: cpu)", "(default: learned)", "(default: ./runs/<task>)",
                                  "(default: ./runs/demos/<task>", "(default: 0)", "(default: off)"],
                     "plan.py": ["(default: 10)", "(default: 2)", "(default: measured)",
                                 "(default: ./runs/<task>/models)", "(default: off)"]}[command]:
        assert fragment in " ".join(text.split()), fragment


def test_help_states_the_fit_defaults():
    """The defaults the help text spells out for options left to ``FitConfig`` are its defaults."""
    from lfd.learning.learn import FitConfig
    cfg = FitConfig()
    text = " ".join(_parsers()["train.py"].format_help().split())
    assert f"FitConfig's, {cfg.restarts})" in text
    assert f"FitConfig's, {' '.join(map(str, cfg.offsets))})" in text
    assert f"FitConfig's, {cfg.floor_task:g})" in text and f"FitConfig's, {cfg.floor_joint:g})" in text
    assert f"(default: {cfg.covariance})" in text and f"(default: {cfg.init})" in text
    assert f"(default: {cfg.band})" in text


def test_one_landmark_vocabulary_across_train_and_plan():
    """train.py's --tool/--env take the names plan.py's variants are made of (the paper's
    learned / manual / arbitrary); the former FitConfig names stay accepted."""
    from lfd.train_cli import ENV_CHOICES, TOOL_CHOICES, parse_args
    from sim.evaluate import VARIANTS

    def chosen(*extra):
        a = parse_args(["--task", "powder", *extra])
        return a.tool, a.env

    assert chosen() == ("learn", "learn")
    assert chosen("--tool", "arbitrary", "--env", "manual") == ("gripper", "bowl")
    assert chosen("--tool", "manual") == ("tip", "learn")
    assert chosen("--tool", "gripper", "--env", "bowl") == ("gripper", "bowl")  # the former names
    assert chosen("--tool", "tip", "--env", "learn") == ("tip", "learn")
    for v in VARIANTS:
        if "+" in v.name:
            tool, env = v.name.split("+")
            assert (TOOL_CHOICES[tool], ENV_CHOICES[env]) == (v.tool, v.env), v.name


@pytest.mark.parametrize("device", ["cpu", "cpu:0", "cuda", "cuda:1", "mps", "meta"])
def test_device_takes_any_torch_device_string(device):
    from lfd.learning.learn import FitConfig
    from lfd.train_cli import parse_args
    assert parse_args(["--task", "powder", "--device", device]).device == device
    assert FitConfig(device=device).device == device


@pytest.mark.parametrize("device", ["gpu", "tpu", "cuda:x", "", "cpu cuda"])
def test_device_that_is_not_a_torch_device_is_one_line_exit_2(device, tmp_path, capsys):
    r = run_cli(*entry_point("train.py"), ["--task", "powder", "--device", device, "--out", tmp_path / "o"],
                capsys)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr
    assert lines[0].startswith(f"train.py: error: --device {device!r} is not a torch device string"), lines[0]
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("bug", [RuntimeError, ValueError])
def test_failed_train_leaves_no_out_folder_and_keeps_the_exception(synth_dir, tmp_path, monkeypatch, bug):
    """A bug inside the fit is not swallowed (its traceback is the report: a ValueError is not
    made a user's error, only the fit's own ``FitError``), and the folders the run created are
    removed; a folder that existed before keeps what it held."""
    import lfd.learning.learn
    import train
    from lfd.errors import UserInputError

    def broken_fit(*args, **kwargs):
        raise bug("a bug in the fit")

    monkeypatch.setattr(lfd.learning.learn, "fit", broken_fit)
    argv = ["--task", "powder", "--demos", str(synth_dir), "--restarts", "1", "--time-steps", "5"]
    out = tmp_path / "a" / "b" / "out"
    with pytest.raises(bug, match="a bug in the fit") as info:
        train.main([*argv, "--out", str(out)])
    assert not isinstance(info.value, UserInputError)
    assert not (tmp_path / "a").exists()
    existing = tmp_path / "mine"
    existing.mkdir()
    (existing / "notes.txt").write_text("keep me")
    with pytest.raises(bug, match="a bug in the fit"):
        train.main([*argv, "--out", str(existing)])
    assert (existing / "notes.txt").read_text() == "keep me"


def test_failed_train_keeps_what_else_was_written_into_the_folders_it_created(synth_dir, tmp_path, monkeypatch):
    """A first run in a fresh folder creates ``runs/``, generates the demonstrations into
    ``runs/demos/...`` and fails in the fit: its ``--out`` goes, the demonstrations stay."""
    import lfd.learning.learn
    import train

    demos = tmp_path / "runs" / "demos" / "powder"

    def broken_fit(*args, **kwargs):
        demos.mkdir(parents=True)  # what ensure_demos writes before the fit
        (demos / "demo_000.npz").write_bytes(b"minutes of work")
        raise RuntimeError("a bug in the fit")

    monkeypatch.setattr(lfd.learning.learn, "fit", broken_fit)
    out = tmp_path / "runs" / "powder" / "models" / "learn-learn"
    with pytest.raises(RuntimeError, match="a bug in the fit"):
        train.main(["--task", "powder", "--demos", str(synth_dir), "--restarts", "1", "--time-steps", "5",
                    "--out", str(out)])
    assert (demos / "demo_000.npz").read_bytes() == b"minutes of work"
    assert not (tmp_path / "runs" / "powder").exists()


def test_failed_train_keeps_demonstrations_generated_inside_its_out(synth_dir, tmp_path, monkeypatch):
    """``--out runs`` in a fresh folder: the default demonstrations are generated into
    ``runs/demos/powder``, inside ``--out``; a failed fit removed all of ``runs/`` with them."""
    import lfd.learning.learn
    import lfd.train_cli
    import train

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(lfd.train_cli, "ensure_demos",  # the simulator's generator, stood in for by a copy
                        lambda task, demos_dir, seed: shutil.copytree(synth_dir, demos_dir, dirs_exist_ok=True))

    def broken_fit(*args, **kwargs):
        (tmp_path / "runs" / "half_written.pt").write_bytes(b"")
        raise RuntimeError("a bug in the fit")

    monkeypatch.setattr(lfd.learning.learn, "fit", broken_fit)
    with pytest.raises(RuntimeError, match="a bug in the fit"):
        train.main(["--task", "powder", "--restarts", "1", "--time-steps", "5", "--out", "runs"])
    kept = sorted(p.relative_to(tmp_path).as_posix() for p in (tmp_path / "runs").rglob("*"))
    assert kept == ["runs/demos", "runs/demos/powder",
                    *sorted(f"runs/demos/powder/{p.name}" for p in Path(synth_dir).iterdir())], kept


def test_quiet_cwd_default_out_and_no_tensorboard(synth_dir, tmp_path, monkeypatch, capsys):
    """--quiet drops the per-iteration lines; without --out the model goes to ./runs/<task> in the
    current working directory; without TensorBoard one warning says so and the run goes on."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setitem(sys.modules, "torch.utils.tensorboard", None)  # import fails: not installed
    r = run_cli(*entry_point("train.py"), ["--task", "powder", "--demos", synth_dir, "--restarts", "2",
                                           "--time-steps", "5", "--quiet"], capsys)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "runs" / "powder" / "model.pt").is_file()
    assert not (tmp_path / "runs" / "powder" / "tensorboard").exists()
    assert " iter " not in r.stdout and "learned in" in r.stdout
    warned = [line for line in r.stderr.splitlines() if "TensorBoard is not installed" in line]
    assert len(warned) == 1 and warned[0].startswith("train.py: warning: "), r.stderr


def test_progress_lines_without_quiet(synth_dir, tmp_path, capsys):
    r = run_cli(*entry_point("train.py"), ["--task", "powder", "--demos", synth_dir, "--restarts", "1",
                                           "--time-steps", "5", "--out", tmp_path / "o"], capsys)
    assert r.returncode == 0, r.stderr
    assert " iter 1: loss " in r.stdout
    assert any((tmp_path / "o" / "tensorboard").iterdir())


def test_tensorboard_shows_every_features_spread_with_the_attitude(synth_dir, tmp_path, capsys):
    """The final model's per-step standard deviations in TensorBoard name every feature: the
    joints, the tool point and, with the attitude features, the gripper's two axes (they were left
    out)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    r = run_cli(*entry_point("train.py"), ["--task", "powder", "--demos", synth_dir, "--restarts", "1",
                                           "--time-steps", "5", "--features", "attitude", "--quiet",
                                           "--out", tmp_path / "o"], capsys)
    assert r.returncode == 0, r.stderr
    ev = EventAccumulator(str(tmp_path / "o" / "tensorboard" / "session-0"))
    ev.Reload()
    spreads = [t for t in ev.Tags()["scalars"] if t.startswith("features/std/")]
    assert len(spreads) == 7 + 9 and "features/std/task_z" in spreads and "features/std/gripper_y_z" in spreads
    assert len(ev.Scalars("features/std/gripper_x_x")) == 5
    # a fresh fit into the same folder replaces the earlier fit's run (two fits were one curve)
    steps = [e.step for e in ev.Scalars("loss/all")]
    r = run_cli(*entry_point("train.py"), ["--task", "powder", "--demos", synth_dir, "--restarts", "1",
                                           "--time-steps", "5", "--features", "attitude", "--quiet",
                                           "--out", tmp_path / "o"], capsys)
    assert r.returncode == 0, r.stderr
    assert [p.name for p in (tmp_path / "o" / "tensorboard").iterdir()] == ["session-0"]
    again = EventAccumulator(str(tmp_path / "o" / "tensorboard" / "session-0"))
    again.Reload()
    assert [e.step for e in again.Scalars("loss/all")] == steps
    # a fit refused before its first event writes no run (one demonstration for a learned landmark)
    import shutil
    one = tmp_path / "one"
    one.mkdir()
    for name in ("demo_000.npz", "task.json"):
        shutil.copy(Path(synth_dir) / name, one / name)
    (tmp_path / "p").mkdir()
    r = run_cli(*entry_point("train.py"), ["--task", "powder", "--demos", one, "--restarts", "1",
                                           "--time-steps", "5", "--quiet", "--out", tmp_path / "p"], capsys)
    assert r.returncode == 2 and "at least 2 demonstrations" in r.stderr, r.stderr
    assert not (tmp_path / "p" / "tensorboard").exists()


@pytest.mark.parametrize("name", ["model.pt", "config.json"])
def test_plan_model_given_a_file_asks_for_the_folder(tmp_path, capsys, name):
    d = tmp_path / "m"
    d.mkdir()
    (d / name).write_bytes(b"x")
    for given in (d / name, tmp_path / "absent" / name):
        r = run_cli(*entry_point("plan.py"), ["--model", given], capsys)
        assert r.returncode == 2, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and "pass the model's folder" in lines[0], lines
        assert f"--model {given.parent}" in lines[0]


def test_a_users_own_task_trains_and_plans_without_the_simulator(tmp_path, capsys):
    """A task.json naming a task lfd does not ship (``reach``) trains with ``--task reach`` and
    plans with ``TaskPlanner`` and the user's own collision callables; without ``--demos`` it is
    refused with one line (only the built-in tasks have generated demonstrations)."""
    from lfd.learning.model import TaskModel
    from lfd.learning.synthetic import make_synthetic
    from lfd.learning.tasks import TaskSpec
    from lfd.planning.task_planner import TaskPlanner, TaskPlannerSettings
    from lfd.robot.kinematics import KinematicModel
    from lfd.train_cli import main

    reach = TaskSpec(name="reach", dt=0.1, time_steps=4, manual_tool_point=(0.0, 0.0, 0.1),
                     reference_landmark="bowl")
    kin = KinematicModel.from_spec()
    ds, _ = make_synthetic(kin, n_demos=3, time_steps=4, Z=2, seed=1, task=reach, samples_per_step=(3, 5))
    save_demos(tmp_path / "demos", ds)
    out = tmp_path / "model"
    r = run_cli(main, "lfd-train", ["--task", "reach", "--demos", str(tmp_path / "demos"), "--out", str(out),
                                    *RUN, "--quiet"], capsys)
    assert r.returncode == 0, r.stderr
    model = TaskModel.load(out, kin=kin)
    assert model.task is not None and model.task.name == "reach"
    planner = TaskPlanner(model, lambda q: False, lambda a, b: False, settings=TaskPlannerSettings(n_vertices=60))
    poses = np.stack([ds.demos[0].landmarks[i] for i in range(len(ds.landmark_names))])
    planner.update_landmarks(list(ds.landmark_names), poses)
    res = planner.plan(ds.demos[0].q[0], 0)
    assert res.ok and res.time_steps[-1] == 3
    for argv, fragment in ((["--task", "reach"], "give --demos DIR"),
                           (["--task", "re ach", "--demos", str(tmp_path / "demos")], "--task must be a name"),
                           (["--task", "powder", "--demos", str(tmp_path / "demos"), *RUN],
                            "demonstrations of task 'reach', not 'powder'")):
        bad = run_cli(main, "lfd-train", argv, capsys)
        assert bad.returncode == 2 and fragment in bad.stderr and bad.stderr.count("\n") == 1, bad.stderr
    # the same set without its task.json (the README's own-demonstrations path): trained as task
    # 'reach' at the files' dt, with a note (the model named no task, so no planner could use it
    # without dt=, and --subsample was refused)
    (tmp_path / "demos" / "task.json").unlink()
    r = run_cli(main, "lfd-train", ["--task", "reach", "--demos", str(tmp_path / "demos"), "--out",
                                    str(tmp_path / "bare"), *RUN, "--subsample", "2", "--quiet"], capsys)
    assert r.returncode == 0, r.stderr
    assert "has no task.json: task 'reach' is learned from samples every 0.1 s, one in 2 kept (a step of 0.2 s)" in r.stdout
    bare = TaskModel.load(tmp_path / "bare", kin=kin)
    assert bare.task is not None and (bare.task.name, bare.task.dt, bare.time_steps) == ("reach", 0.2, 4)
    bare_planner = TaskPlanner(bare, lambda q: False, lambda a, b: False, settings=TaskPlannerSettings(n_vertices=60))
    bare_planner.update_landmarks(list(ds.landmark_names), poses)
    assert bare_planner.plan(ds.demos[0].q[0], 0).ok


def test_summary_names_the_distance_to_each_reference_point(synth_dir, tmp_path, capsys):
    """``ground_truth.json``'s ``reference_points`` (e.g. where the demonstrator aimed) are
    evaluation only: the summary gives the learned tool point's distance to each, and to the
    hidden task point, and prints them."""
    import shutil
    demos = tmp_path / "demos"
    shutil.copytree(synth_dir, demos)
    gt = json.loads((demos / "ground_truth.json").read_text()) if (demos / "ground_truth.json").is_file() else {}
    gt.setdefault("tool_point", [0.0, 0.0, 0.15])
    gt["reference_points"] = {"aim": [0.0, 0.0, 0.3], "handle": [0.0, 0.0, 0.0]}
    (demos / "ground_truth.json").write_text(json.dumps(gt))
    out = tmp_path / "out"
    assert _train_main(["--task", "powder", "--demos", str(demos), "--out", str(out), "--restarts", "1",
                        "--time-steps", "5"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    tool = np.array(summary["tool_point"])
    dist = summary["reference_point_distances_m"]
    assert dist == pytest.approx({"aim": float(np.linalg.norm(tool - [0, 0, 0.3])),
                                  "handle": float(np.linalg.norm(tool))})
    printed = capsys.readouterr().out
    assert f"{dist['aim'] * 100:.1f} cm from the demonstrations' aim" in printed
    assert "cm from the demonstrator's hidden task point" in printed


def test_a_roadmap_the_memory_cannot_hold_is_refused_before_the_build(tmp_path, monkeypatch, capsys):
    """``--roadmap-size 100000`` (the largest accepted) needs about 50-95 GB: it was built until the
    kernel killed the run. Refused in one line when the available memory cannot hold the build,
    per worker with --evaluate; the default size of the built-in tasks fits in a few GB."""
    import sim.plan_cli as cli
    monkeypatch.setattr(cli, "available_mb", lambda: 4000.0)
    cli.check_roadmap_memory(None, 48)  # the pour's default, 2000 vertices: 2.9 GB
    cli.check_roadmap_memory(None, 24, processes=2)  # the powder's, twice: 2.9 GB
    with pytest.raises(cli.UsageError, match=r"^the default roadmap size \(2000\): .*needs about 6 GB \(3 GB in each of 2 workers\), .* 4 GB available; "
                                             r"take fewer vertices or fewer --workers"):
        cli.check_roadmap_memory(None, 48, processes=2)
    with pytest.raises(cli.UsageError, match=r"100000 vertices for a 48-step model needs about 95 GB, and"):
        cli.check_roadmap_memory(100_000, 48)
    monkeypatch.setattr(cli, "available_mb", lambda: None)  # unknown: not refused
    cli.check_roadmap_memory(100_000, 48)
    capsys.readouterr()
    monkeypatch.setattr(cli, "available_mb", lambda: 4000.0)  # the build fits, its growth to 3 x would not
    cli.check_roadmap_memory(1200, 48)  # 2.1 GB; 4.4 GB at 3,600 vertices
    assert capsys.readouterr().err.startswith("note: the roadmap may grow after landmark moves to 3600 vertices, "
                                              "about 4.4 GB, more than the 3.9 GB available")
    cli.check_roadmap_memory(500, 48)  # 1.5 GB; 2.4 GB grown: no note
    cli.check_roadmap_memory(1200, 48, may_grow=False)  # a plan that is not executed: nothing moves
    assert capsys.readouterr().err == ""
    monkeypatch.setattr(cli, "available_mb", lambda: 1500.0)
    model = _model(tmp_path, names=("bowl",))
    monkeypatch.chdir(tmp_path)
    r = run_cli(cli.main, "plan.py", ["--model", str(model), "--roadmap-size", "20000"], capsys)
    assert r.returncode == 2 and "--roadmap-size 20000: a roadmap of 20000 vertices for a 4-step model" in r.stderr
    assert not (tmp_path / "runs").exists()


def test_the_evaluations_memory_check_counts_the_trained_models_own_time_steps(tmp_path, monkeypatch, capsys):
    """--evaluate estimated every roadmap at the built-in task's number of steps (the powder's 24),
    whatever the trained models had learned; a trained model's own T counts, and a variant still
    to be trained counts at the task's T."""
    import sim.plan_cli as cli
    monkeypatch.setattr(cli, "available_mb", lambda: 1500.0)
    argv = _evaluate_models("powder")(tmp_path, tmp_path)[1:] + ["--roadmap-size", "20000"]
    r = run_cli(cli.main, "plan.py", argv, capsys)
    assert r.returncode == 2 and "a roadmap of 20000 vertices for a 4-step model" in r.stderr
    r = run_cli(cli.main, "plan.py", argv[:argv.index("--variants") + 1] + ["learned+learned", "arbitrary+manual"]
                + argv[argv.index("--variants") + 2:], capsys)
    assert r.returncode == 2 and "a roadmap of 20000 vertices for a 24-step model" in r.stderr
    assert not (tmp_path / "eval").exists()
