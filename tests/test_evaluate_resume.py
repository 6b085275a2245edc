"""``plan.py --evaluate`` resumes: finished runs in ``runs.jsonl`` are kept and never run again.

``sim.evaluate.evaluate`` runs the jobs in this process when ``workers=1``, looking ``run_one`` up
in its module, so a fast fake (no PyBullet, no planning) stands in for the minutes-long real runs
and records which (variant, scenario) pairs were asked for. Models are two empty files per
variant: ``ensure_model`` only checks that they exist.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lfd.cli import UsageError
import sim.evaluate as ev
import sweep_fakes
import sim.report as report
from sim.scenarios import draw_scenarios

TASK = "powder"
VARIANTS = ("learned+learned", "manual+manual")
N = 3


@functools.lru_cache(maxsize=None)
def _drawn(task: str, n: int, base_seed: int = 0) -> tuple:
    """``draw_scenarios`` once per set: the draw checks every scene's reachability in PyBullet,
    seconds per scene, and these tests only need the scenes' seeds."""
    return tuple(draw_scenarios(task, n, base_seed))


@pytest.fixture(autouse=True)
def _cached_draws(monkeypatch):
    monkeypatch.setattr(ev, "draw_scenarios", lambda *a, **kw: list(_drawn(*a, **kw)))


def _settings(**kw) -> ev.EvalSettings:
    return ev.EvalSettings(task=TASK, n_scenarios=N, seeds=(0,), roadmap_size=10, workers=1,
                           variants=VARIANTS, **kw)


@pytest.fixture
def models(tmp_path) -> Path:
    root = tmp_path / "models"
    for v in ev.VARIANTS:
        d = ev.model_dir_for(root, v)
        d.mkdir(parents=True, exist_ok=True)  # two variants share a model
        (d / "model.pt").write_bytes(b"")
        (d / "config.json").write_text("{}")
    return root


def _row(variant: str, scenario: int, success: bool = True) -> dict:
    """A run as ``run_one`` reports it with the default latency mode (the keys ``summarize`` and
    the resume read)."""
    return {"variant": variant, "scenario": scenario, "success": success, "reason": "fake",
            "contacts": [], "fraction_in_bowl": 1.0 if success else 0.0, "initial_ms": 5.0,
            "replan_ms": [1.0, 2.0], "wall_s": 0.0, "roadmap_vertices": 10, "pace": ev.EXEC_PACE,
            "latency": "measured"}


class FakeRunOne:
    """Records ``(variant, scenario)`` of every call; raises ``KeyboardInterrupt`` on call
    number ``interrupt_at`` (1-based) as Ctrl-C would in the middle of a run."""

    def __init__(self, interrupt_at: int | None = None):
        self.calls: list[tuple[str, int]] = []
        self.interrupt_at = interrupt_at

    def __call__(self, task, scenario, variant, model_dir, roadmap_size, video_path=None, with_path=False,
                 latency="measured"):
        assert task == TASK and Path(model_dir).name == variant.model_key
        if self.interrupt_at is not None and len(self.calls) + 1 == self.interrupt_at:
            raise KeyboardInterrupt
        self.calls.append((variant.name, scenario.seed))
        row = {**_row(variant.name, scenario.seed), "latency": latency}
        if with_path:  # the executed tool point, as sim.execute records it
            row["task_point_path"] = [[0.5, 0.1 * scenario.seed, 0.0], [0.6, 0.2, 0.1], [0.7, 0.3, 0.2]]
        return row


def _all_pairs() -> list[tuple[str, int]]:
    seeds = [sc.seed for sc in _drawn(TASK, N, 0)]
    return [(v, s) for v in VARIANTS for s in seeds]


def _logged(out: Path) -> list[tuple[str, int]]:
    pairs = []
    for line in (out / "runs.jsonl").read_text().splitlines():
        try:
            r = json.loads(line)
        except ValueError:
            continue
        pairs.append((r["variant"], r["scenario"]))
    return pairs


def _no_constant(name):
    raise ValueError(f"results.json is not strict JSON: {name}")


def _check_results(out: Path, payload: dict) -> None:
    on_disk = json.loads((out / "results.json").read_text(), parse_constant=_no_constant)
    assert on_disk["variants"].keys() == payload["variants"].keys() == set(VARIANTS)
    seeds = sorted(s for _, s in _all_pairs()[:N])
    for name in VARIANTS:
        v = on_disk["variants"][name]
        assert v["n_scenarios"] == N
        assert sorted(r["scenario"] for r in v["scenarios"]) == seeds


def test_interrupted_evaluation_resumes_with_only_the_missing_runs(tmp_path, models, monkeypatch):
    out = tmp_path / "eval"
    first = FakeRunOne(interrupt_at=3)
    monkeypatch.setattr(ev, "run_one", first)
    with pytest.raises(KeyboardInterrupt):
        ev.evaluate(_settings(), out, models, resume=True)
    assert first.calls == _all_pairs()[:2]
    assert _logged(out) == first.calls  # each finished run is on disk at once
    assert not (out / "results.json").exists()

    second = FakeRunOne()
    monkeypatch.setattr(ev, "run_one", second)
    payload = ev.evaluate(_settings(), out, models, resume=True)
    assert second.calls == _all_pairs()[2:]  # only the missing pairs, none twice
    assert sorted(_logged(out)) == sorted(_all_pairs())
    _check_results(out, payload)

    # every run's task-point path is on disk, named by its row, and the row stays small
    for line in (out / "runs.jsonl").read_text().splitlines():
        r = json.loads(line)
        assert r["task_point_path"] == f"paths/{r['variant']}_measured_{r['scenario']}.npy"
        path = np.load(out / r["task_point_path"])
        assert path.shape == (3, 3) and path[0, 1] == pytest.approx(0.1 * r["scenario"])

    third = FakeRunOne()  # everything done: nothing runs, the table is rebuilt from the log
    monkeypatch.setattr(ev, "run_one", third)
    assert ev.evaluate(_settings(), out, models, resume=True)["variants"] == payload["variants"]
    assert third.calls == []


def test_preseeded_log_is_kept_and_counted(tmp_path, models, monkeypatch):
    out = tmp_path / "eval"
    out.mkdir()
    pairs = _all_pairs()
    kept = [pairs[0], pairs[4]]
    other_set = ("learned+learned", 999_999)  # a scenario of another seed set: kept, not counted
    rows = [_row(v, s, success=False) for v, s in kept] + [_row(*other_set)]
    (out / "runs.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    fake = FakeRunOne()
    monkeypatch.setattr(ev, "run_one", fake)
    payload = ev.evaluate(_settings(), out, models, resume=True)
    assert fake.calls == [p for p in pairs if p not in kept]
    _check_results(out, payload)
    # the pre-seeded rows (failures) are the ones counted, not re-run successes
    assert payload["variants"]["learned+learned"]["success_rate"] == pytest.approx(2 / 3)
    assert payload["variants"]["manual+manual"]["success_rate"] == pytest.approx(2 / 3)


def test_truncated_last_line_does_not_stop_the_resume(tmp_path, models, monkeypatch):
    """A run cut while writing its line (``kill -9``) is simply run again."""
    out = tmp_path / "eval"
    out.mkdir()
    pairs = _all_pairs()
    whole = json.dumps(_row(*pairs[0]))
    cut = json.dumps(_row(*pairs[1]))[:40]  # half-written, no newline
    (out / "runs.jsonl").write_text(whole + "\n" + cut)
    fake = FakeRunOne()
    monkeypatch.setattr(ev, "run_one", fake)
    payload = ev.evaluate(_settings(), out, models, resume=True)
    assert fake.calls == pairs[1:]
    _check_results(out, payload)


def test_run_after_a_truncated_line_is_not_lost(tmp_path, models, monkeypatch):
    out = tmp_path / "eval"
    out.mkdir()
    pairs = _all_pairs()
    (out / "runs.jsonl").write_text(json.dumps(_row(*pairs[0])) + "\n" + json.dumps(_row(*pairs[1]))[:40])
    monkeypatch.setattr(ev, "run_one", FakeRunOne())
    ev.evaluate(_settings(), out, models, resume=True)
    again = FakeRunOne()
    monkeypatch.setattr(ev, "run_one", again)
    ev.evaluate(_settings(), out, models, resume=True)
    assert again.calls == []


def test_runs_of_another_latency_mode_are_run_again(tmp_path, models, monkeypatch):
    """A log made with one latency mode is not counted for another; rows logged without the key
    were made in a frozen world ("none"), and rows of a removed dwell option other than the
    paper's interval are redone."""
    out = tmp_path / "eval"
    monkeypatch.setattr(ev, "run_one", FakeRunOne())
    ev.evaluate(_settings(), out, models, resume=True)
    again = FakeRunOne()
    monkeypatch.setattr(ev, "run_one", again)
    payload = ev.evaluate(replace(_settings(), latency="none"), out, models, resume=True)
    assert again.calls == _all_pairs()
    assert payload["latency"] == "none"
    assert all(v["latency_mode"] == ["none"] for v in payload["variants"].values())
    # both settings' rows stay in the log, each naming its own task-point path
    rows = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    files = [r["task_point_path"] for r in rows]
    assert len(rows) == 2 * len(_all_pairs()) and len(set(files)) == len(files)
    assert all((out / f).is_file() for f in files)
    # old rows: no latency key (a frozen world) counts for "none"; a dwell of "expected" does not
    log = out / "runs.jsonl"
    old = [dict(r) for r in rows if r["latency"] == "none"]
    for i, r in enumerate(old):
        del r["latency"]
        if i == 0:
            r["dwell"] = "expected"
    log.write_text("".join(json.dumps(r) + "\n" for r in old))
    third = FakeRunOne()
    monkeypatch.setattr(ev, "run_one", third)
    ev.evaluate(replace(_settings(), latency="none"), out, models, resume=True)
    assert third.calls == [(old[0]["variant"], old[0]["scenario"])]
    for bad in ("forever", "1e300", 61):  # (1e300 s of simulated holding ran for ever)
        with pytest.raises(ValueError, match="latency must be"):
            replace(_settings(), latency=bad)
    assert replace(_settings(), latency=0.5).latency == "0.5"


def test_runs_paced_before_the_clock_are_run_again(tmp_path, models, monkeypatch):
    """Rows logged without ``pace`` were executed with the old per-visited-step timing: redone."""
    out = tmp_path / "eval"
    monkeypatch.setattr(ev, "run_one", FakeRunOne())
    ev.evaluate(_settings(), out, models, resume=True)
    log = out / "runs.jsonl"
    rows = [json.loads(line) for line in log.read_text().splitlines()]
    rows[0].pop("pace")
    log.write_text("".join(json.dumps(r) + "\n" for r in rows))
    again = FakeRunOne()
    monkeypatch.setattr(ev, "run_one", again)
    ev.evaluate(_settings(), out, models, resume=True)
    assert again.calls == [(rows[0]["variant"], rows[0]["scenario"])]


def test_the_replan_latency_is_that_of_re_plans_after_a_sensed_move():
    """The anytime re-plans on a growing roadmap (``replan_kind`` "growth") are ``improve_ms``;
    they were counted in ``replan_ms`` too, the column the paper's latency stands beside (the
    pour's median 498 ms where its move re-plans took 97 ms)."""
    v = next(x for x in ev.VARIANTS if x.name == "learned+learned")
    row = {**_row(v.name, 0), "replan_ms": [3.0, 400.0, 500.0, 5.0], "replan_kind": ["move", "growth", "growth", "move"],
           "replan_update_ms": [10.0, 1000.0, 900.0, 20.0], "path_check_ms": [1.0, 1.0, 1.0, 1.0],
           "plan_statuses": ["ok"] * 5}
    s = report.summarize([row], v, 1.0)
    assert s["replan_ms"]["median"] == pytest.approx(4.0) and s["replan_ms"]["mean"] == pytest.approx(4.0)
    assert s["reaction_ms"]["median"] == pytest.approx((14.0 + 26.0) / 2)
    assert s["improve_ms"]["median"] == pytest.approx((1401.0 + 1401.0) / 2)


def test_summary_reaction_times_only_from_timed_runs():
    """``reaction_ms`` adds each re-plan's landmark update to its search; runs logged before the
    update was timed count for the searches but not for the reaction or the build."""
    v = next(x for x in ev.VARIANTS if x.name == "learned+learned")
    old = _row(v.name, 0)  # replan_ms [1, 2], no update times
    new = {**_row(v.name, 1), "replan_ms": [3.0, 4.0], "replan_update_ms": [10.0, 30.0], "build_ms": 7.0}
    s = report.summarize([old, new], v, 1.0)
    assert s["replan_ms"]["median"] == pytest.approx(2.5)  # 1, 2, 3, 4
    assert s["reaction_ms"]["median"] == pytest.approx(23.5)  # 13, 34
    assert s["build_ms"]["median"] == pytest.approx(7.0)
    assert s["reaction_ms"]["p95"] == pytest.approx(13 + 0.95 * (34 - 13))
    assert s["reaction_ms"]["mean"] == pytest.approx(23.5) and s["replan_ms"]["mean"] == pytest.approx(2.5)
    # a run whose update times do not pair with its searches is left out of the reaction
    odd = {**_row(v.name, 2), "replan_update_ms": [5.0], "build_ms": 1.0}
    assert report.summarize([new, odd], v, 1.0)["reaction_ms"]["median"] == pytest.approx(23.5)
    only_old = report.summarize([old], v, 1.0)
    assert math.isnan(only_old["reaction_ms"]["median"]) and math.isnan(only_old["build_ms"]["median"])
    table = report.format_table({v.name: s, "old": only_old}, TASK)
    assert "24ms" in table and table.splitlines()[-2].split()[-3:] == ["-", "-", "-"]  # no reaction, mean, tilt
    new_line = next(line for line in table.splitlines() if line.startswith("Learned"))
    assert new_line.split()[-3:-1] == ["24ms", "24ms"]  # the reaction's median and mean (13, 34 ms)


def test_stats_leave_out_what_was_not_measured():
    """``{median, p95, mean}`` over the measured values only (None and NaN left out; the
    benchmarks pass None for a scene without a reaction); all NaN when none was measured."""
    s = report.stats([10.0, None, math.nan, 20.0, 40.0])
    assert s == {"median": 20.0, "p95": pytest.approx(20 + 0.9 * 20), "mean": pytest.approx(70 / 3)}
    assert all(math.isnan(x) for x in report.stats([None, math.nan]).values())
    assert report.strict_json(report.stats([])) == {"median": None, "p95": None, "mean": None}


def test_a_scenario_set_is_at_most_the_seeds_stride():
    """Scenario ``S * SEED_STRIDE + i`` of set S: a larger set would share scenes with set S + 1."""
    from sim.scenarios import SEED_STRIDE, check_set_size
    assert check_set_size(SEED_STRIDE) == SEED_STRIDE
    with pytest.raises(ValueError, match=f"n_scenarios must be at most {SEED_STRIDE}"):
        ev.EvalSettings(task=TASK, n_scenarios=SEED_STRIDE + 1)
    with pytest.raises(ValueError, match="the number of scenarios must be at least 1, got 0"):
        draw_scenarios(TASK, 0)


def test_summary_tilt_error_against_the_demonstrations():
    """``tilt_error_deg`` (the tool's largest tilt minus the demonstrations' mean, per run) is
    summarized as the median and p95 of its absolute value, its sign as ``tilt_bias_deg``; runs
    without it (no demonstrations to compare with) are left out."""
    v = next(x for x in ev.VARIANTS if x.name == "learned+learned")
    errs = [-12.0, -8.0, -4.0, 2.0]
    rows = [{**_row(v.name, i), "tilt_error_deg": e, "planned_tilt_error_deg": e - 1.0} for i, e in enumerate(errs)]
    rows.append({**_row(v.name, 9), "tilt_error_deg": math.nan})
    s = report.summarize(rows, v, 1.0)
    assert s["tilt_error_deg"]["median"] == pytest.approx(6.0)  # |.| = 2, 4, 8, 12
    assert s["tilt_error_deg"]["p95"] == pytest.approx(8 + 0.85 * 4)
    assert s["planned_tilt_error_deg"]["median"] == pytest.approx(7.0)  # 1, 5, 9, 13
    assert s["tilt_bias_deg"] == pytest.approx(-6.0)
    assert "6 / 11 deg" in report.format_table({v.name: s}, TASK)


def test_plans_not_found_are_no_latency_and_runs_that_never_moved_no_tilt_error():
    """A first plan that was not found leaves the run unmoved: its 0° tilt is not a tilt error, and
    its answer's time is no planning latency; a re-plan not found is left out of the re-plan and
    reaction times (an 'unreachable' comes back at once and pulled them towards 0)."""
    v = next(x for x in ev.VARIANTS if x.name == "learned+learned")
    moved = {**_row(v.name, 0), "plan_statuses": ["ok", "ok", "unreachable"], "replan_update_ms": [10.0, 30.0],
             "replan_kind": ["move", "move"], "initial_ms": 100.0, "replan_ms": [50.0, 0.0],
             "tilt_error_deg": -4.0, "planned_tilt_error_deg": -3.0}
    stuck = {**_row(v.name, 1, success=False), "plan_statuses": ["no_path"], "initial_ms": 0.5, "replan_ms": [],
             "replan_update_ms": [], "tilt_error_deg": -116.0, "planned_tilt_error_deg": -116.0}
    s = report.summarize([moved, stuck], v, 1.0)
    assert s["initial_ms"]["median"] == pytest.approx(100.0) and s["replan_ms"]["median"] == pytest.approx(50.0)
    assert s["reaction_ms"]["median"] == pytest.approx(60.0) and s["reaction_ms"]["p95"] == pytest.approx(60.0)
    assert s["tilt_error_deg"]["median"] == pytest.approx(4.0) and s["tilt_bias_deg"] == pytest.approx(-4.0)
    assert s["success_rate"] == 0.5 and s["n_scenarios"] == 2  # the run still counts as a failure


def test_missing_model_is_trained_with_the_learning_seed_not_the_scenario_seed(tmp_path, monkeypatch):
    """Tables of different base seeds must compare the same models: a variant trained on demand
    gets train.py's learning seed (0), whatever ``--seed`` draws the scenarios."""
    models = tmp_path / "models"
    commands = []
    monkeypatch.setattr(ev, "train_main", sweep_fakes.fake_train(commands))  # lfd.train_cli.main, in-process
    monkeypatch.setattr(ev, "run_one", FakeRunOne())
    payload = ev.evaluate(replace(_settings(), seeds=(7,)), tmp_path / "eval", models)
    assert len(commands) == 2  # learn-learn and tip-bowl, each once
    for cmd in commands:
        assert cmd[cmd.index("--seed") + 1] == "0"
    assert payload["seeds"] == [7] and payload["demo_seeds"] == [0]
    by_name = {v.name: v for v in ev.VARIANTS}
    assert payload["models"] == {f"{v}@demos0": str(models / by_name[v].model_key) for v in VARIANTS}


def test_missing_model_is_trained_in_this_process(tmp_path, monkeypatch, capsys):
    """``ensure_model`` trains with ``lfd.train_cli.main`` in-process (no script, no subprocess),
    with the variant's landmark choices, into the model folder the evaluation then reads."""
    from helpers import synthetic_demo_dir
    from lfd.train_cli import main as train_main
    demos = synthetic_demo_dir(tmp_path / "demos", 2, 4, 2, (3, 4))
    seen = []

    def small_train(argv):  # the real training, made short
        seen.append(list(argv))
        return train_main([*argv, "--restarts", "1", "--time-steps", "4"])

    monkeypatch.setattr(ev, "train_main", small_train)
    v = next(x for x in ev.VARIANTS if x.name == "arbitrary+manual")
    out = ev.ensure_model(TASK, tmp_path / "models", demos, v)
    assert out == tmp_path / "models" / "gripper-bowl"
    assert (out / "model.pt").is_file() and (out / "summary.json").is_file()
    config = json.loads((out / "config.json").read_text())
    assert config["options"]["tool"] == "gripper" and config["options"]["env"] == "bowl"
    assert seen[0][seen[0].index("--seed") + 1] == "0"
    assert ev.ensure_model(TASK, tmp_path / "models", demos, v) == out and len(seen) == 1  # trained once
    # other demonstrations for a trained model: it was evaluated as it was, without a word; refused
    # before any training (the check reads the recordings alone: an edited task.json is the same set)
    other = synthetic_demo_dir(tmp_path / "demos2", 3, 4, 2, (3, 4))
    with pytest.raises(UsageError, match=r"gripper-bowl was trained on other demonstrations than .*demos2; give"):
        ev.check_trained_on(TASK, tmp_path / "models", other, ev.VARIANTS, (0,))
    task = json.loads((demos / "task.json").read_text())
    (demos / "task.json").write_text(json.dumps({**task, "restarts": 7}))
    ev.check_trained_on(TASK, tmp_path / "models", demos, ev.VARIANTS, (0,))
    with pytest.raises(UsageError, match="trained on other demonstrations"):
        ev.evaluate(replace(_settings(), variants=("arbitrary+manual",)), tmp_path / "eval_other",
                    tmp_path / "models", other)
    assert len(seen) == 1
    # --models naming one model's folder: a new model was trained inside it
    with pytest.raises(UsageError, match=r"a model's own folder \(it holds model.pt or config.json\)"):
        ev.evaluate(_settings(), tmp_path / "eval", out, demos)
    assert not (out / "learn-learn").exists()


def test_runs_of_another_roadmap_size_or_models_folder_are_run_again(tmp_path, models, monkeypatch):
    """``--resume`` counts only the runs made with this task, roadmap size and models folder."""
    out = tmp_path / "eval"
    monkeypatch.setattr(ev, "run_one", FakeRunOne())
    ev.evaluate(_settings(), out, models)
    for change in (dict(roadmap_size=20), dict(models=tmp_path / "models2")):
        again = FakeRunOne()
        monkeypatch.setattr(ev, "run_one", again)
        other = change.get("models", models)
        if other != models:
            import shutil
            shutil.copytree(models, other)
        ev.evaluate(replace(_settings(), **{k: v for k, v in change.items() if k != "models"}), out, other, resume=True)
        assert again.calls == _all_pairs(), change


def test_the_same_models_folder_named_otherwise_counts_on_resume(tmp_path, models, monkeypatch, capsys):
    """``--models mdir``, then ``--resume`` with ``$PWD/mdir`` or ``./mdir`` ran every logged run
    again: the folder is compared by where it is."""
    out = tmp_path / "eval"
    monkeypatch.setattr(ev, "run_one", FakeRunOne())
    monkeypatch.chdir(models.parent)
    ev.evaluate(_settings(), out, Path(models.name))
    rows = [json.loads(x) for x in (out / "runs.jsonl").read_text().splitlines()]
    assert {r["settings"]["models"] for r in rows} == {models.name}  # as given
    for named in (models.resolve(), Path(".") / models.name):
        again = FakeRunOne()
        monkeypatch.setattr(ev, "run_one", again)
        ev.evaluate(_settings(), out, named, resume=True)
        assert again.calls == [] and "other settings" not in capsys.readouterr().err, named


@pytest.mark.parametrize("edit,fragment", [
    (lambda r: r.update(scenario=[r["scenario"]]), "whole-number scenario"),  # was: unhashable type
    (lambda r: r.pop("initial_ms"), "missing or malformed initial_ms"),  # was: KeyError in the table
    (lambda r: r.update(fraction_in_bowl=None), "missing or malformed fraction_in_bowl"),  # was: TypeError
    (lambda r: r.update(settings=5), "settings are a JSON object, got int"),  # was: TypeError
])
def test_hand_edited_log_row_is_named_not_crashed_on(tmp_path, models, monkeypatch, edit, fragment):
    out = tmp_path / "eval"
    out.mkdir()
    pairs = _all_pairs()
    rows = [_row(*pairs[0]), _row(*pairs[1])]
    edit(rows[1])
    (out / "runs.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    fake = FakeRunOne()
    monkeypatch.setattr(ev, "run_one", fake)
    with pytest.raises(UsageError, match=r"runs.jsonl, line 2: ") as info:
        ev.evaluate(_settings(), out, models, resume=True)
    assert fragment in str(info.value) and fake.calls == []


def test_a_log_that_is_not_text_is_refused_and_a_line_nested_too_deep_is_skipped(tmp_path, models, monkeypatch):
    """A non-UTF-8 byte in ``runs.jsonl`` was a UnicodeDecodeError traceback, a line of 100,000
    nested brackets a RecursionError: the first is refused in one line, the second skipped like a
    line cut by an interruption (its run is done again)."""
    out = tmp_path / "eval"
    out.mkdir()
    pairs = _all_pairs()
    (out / "runs.jsonl").write_bytes(json.dumps(_row(*pairs[0])).encode() + b"\n\xff\xfe\n")
    monkeypatch.setattr(ev, "run_one", FakeRunOne())
    with pytest.raises(UsageError, match=r"runs.jsonl: not a log of runs \(not UTF-8"):
        ev.evaluate(_settings(), out, models, resume=True)
    (out / "runs.jsonl").write_text(json.dumps(_row(*pairs[0])) + "\n" + "[" * 100_000 + "]" * 100_000 + "\n")
    fake = FakeRunOne()
    monkeypatch.setattr(ev, "run_one", fake)
    ev.evaluate(_settings(), out, models, resume=True)
    assert fake.calls == pairs[1:]


def test_a_summary_whose_learning_time_is_not_a_number_is_refused_before_any_run(tmp_path, models, monkeypatch):
    """``"learning_time_s": "abc"`` in a model's summary.json: every scene ran, results.json was
    written, and printing the table raised. Now the summary is refused before the first run."""
    v = next(v for v in ev.VARIANTS if v.name == VARIANTS[0])
    (ev.model_dir_for(models, v) / "summary.json").write_text('{"learning_time_s": "abc"}')
    fake = FakeRunOne()
    monkeypatch.setattr(ev, "run_one", fake)
    with pytest.raises(UsageError, match=r"summary.json: learning_time_s must be a number of seconds, got 'abc'"):
        ev.evaluate(_settings(), tmp_path / "eval", models)
    assert fake.calls == []


def test_measured_runs_of_another_cpu_load_are_run_again(tmp_path, models, monkeypatch, capsys):
    """With measured latency the executor and its workers set the CPU's load, which lengthens
    every plan's charged time: ``--resume`` with other workers runs everything again and says
    why; in a frozen world they do not matter; rows logged before they were recorded count."""
    out = tmp_path / "eval"
    monkeypatch.setattr(ev, "run_one", FakeRunOne())
    ev.evaluate(_settings(), out, models)
    rows = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    assert all(r["settings"]["workers"] == 1 and r["settings"]["executor"] == "local" for r in rows)
    capsys.readouterr()
    ev.evaluate(replace(_settings(), workers=2), out, models, resume=True)  # (the fake runs in the workers)
    assert f"{len(rows)} logged run(s)" in capsys.readouterr().err
    log = out / "runs.jsonl"
    redone = [json.loads(line) for line in log.read_text().splitlines()][len(rows):]
    assert sorted((r["variant"], r["scenario"]) for r in redone) == sorted(_all_pairs())
    assert all(r["settings"]["workers"] == 2 for r in redone)
    # rows without the load settings (logged before they were recorded) count for any
    for r in rows:
        del r["settings"]["workers"], r["settings"]["executor"]
    log.write_text("".join(json.dumps(r) + "\n" for r in rows))
    ev.evaluate(replace(_settings(), workers=2), out, models, resume=True)
    assert len(log.read_text().splitlines()) == len(rows)
    # a frozen world: the load is not part of a run
    frozen = tmp_path / "frozen"
    monkeypatch.setattr(ev, "run_one", FakeRunOne())
    ev.evaluate(replace(_settings(), latency="none"), frozen, models)
    n_frozen = len((frozen / "runs.jsonl").read_text().splitlines())
    ev.evaluate(replace(_settings(), latency="none", workers=2), frozen, models, resume=True)
    assert len((frozen / "runs.jsonl").read_text().splitlines()) == n_frozen
    assert ev.run_settings_of(replace(_settings(), executor="ray", address="h:6379"), models)["workers"] == "h:6379"


def test_each_logged_run_keeps_its_own_path_file(tmp_path):
    """A resumed sweep with another setting (roadmap size, models...) runs a scene again beside
    the logged run of it: the second run's task-point path overwrote the first's file, which the
    first row still named. Now each is saved under a name of its own."""
    from sim.runlog import save_path

    row = {"variant": "learned+learned", "scenario": 3, "demo_seed": 0, "latency": "measured"}
    first = save_path(tmp_path, row, [[1.0, 1.0, 1.0]])
    second = save_path(tmp_path, row, [[2.0, 2.0, 2.0]])
    assert first == "paths/learned+learned_measured_3.npy" and second == "paths/learned+learned_measured_3_2.npy"
    assert np.load(tmp_path / first).tolist() == [[1.0, 1.0, 1.0]]
    assert np.load(tmp_path / second).tolist() == [[2.0, 2.0, 2.0]]
