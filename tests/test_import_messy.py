"""Real recorders' phenomena (``lfd.io.cleaning``): dropouts, a tracker slower than the recorder that
stamps its rows, jitter, outliers, and the recordings a killed recorder or a careless copy leave.

Each test writes readings with a known truth (the tracker's rate, its noise, the glitch's row) and
checks what the cleaning recovers and reports, or that a broken file is refused naming its row.
"""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli

from lfd.io.cleaning import clean_joints, clean_track, jitter_mm
from lfd.io.import_csv import main
from lfd.io.raw import RecordingError
from lfd.io.recordings import import_recordings
from lfd.robot.robots import BAXTER_LEFT

DATA = Path(__file__).resolve().parent / "data" / "recordings"
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def _truth(t):
    """A hand's true path (m) at times ``t (K,)``: 0.3 m over 3 s, a little curved."""
    return np.stack([0.6 + 0.1 * t, 0.2 + 0.05 * np.sin(t), 0.1 + 0.0 * t], axis=1)


def _recorded(seed=0, tracker_hz=30.0, recorder_hz=50.0, noise=0.01, span=3.0, drop=0.03, glitch_at=None):
    """A tracker at ``tracker_hz`` with ``noise`` m of jitter per axis, written by a recorder at
    ``recorder_hz`` that stamps each row with its own clock (repeats of the latest reading, a new
    one often 7 us after a repeat) with ``drop`` of its rows NaN, all-zero or zero-quaternion
    dropouts. Returns ``(t (K,), pose (K, 7), where (K,), the glitch's row or None)``."""
    rng = np.random.default_rng(seed)
    frames = np.arange(0.0, span, 1 / tracker_hz)
    pos = _truth(frames) + rng.normal(0, noise, (len(frames), 3))
    glitch_frame = None if glitch_at is None else int(np.searchsorted(frames, glitch_at))
    if glitch_frame is not None:
        pos[glitch_frame] += [0.0, 0.6, 0.0]
    arrival = frames + rng.uniform(0.004, 0.012, len(frames))
    t, pose, last, glitch_row = [], [], -1, None
    for r in np.arange(0.02, span, 1 / recorder_hz):
        k = int(np.searchsorted(arrival, r, side="right")) - 1
        if k < 0:
            continue
        if rng.random() < drop:
            t.append(r)
            pose.append(rng.choice([np.full(7, np.nan), np.zeros(7), np.r_[pos[k], 0, 0, 0, 0]]))
        elif k != last and last >= 0 and rng.random() < 0.5:
            t += [r, r + 7e-6]
            pose += [np.r_[pos[last], IDENTITY], np.r_[pos[k], IDENTITY]]
        else:
            t.append(r)
            pose.append(np.r_[pos[k], IDENTITY])
        if k == glitch_frame and glitch_row is None and k != last:
            glitch_row = len(t) + 1  # the new reading's row (1-based, after the header)
        last = k
    return np.array(t), np.array(pose), np.arange(len(t)) + 2, glitch_row


def _clean(t, pose, where, **kw):
    kw.setdefault("max_gap", 0.5)
    return clean_track("hand", t, pose, where, "hand.csv", "row", np.eye(4), **kw)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_recorder_stamped_tracker_is_read_at_its_own_rate_with_its_jitter(seed):
    t, pose, where, _ = _recorded(seed)
    c = _clean(t, pose, where)
    rep = c.report
    truth_drops = int((~np.isfinite(pose).all(1) | (np.abs(np.nan_to_num(pose)).sum(1) == 0)
                       | (np.linalg.norm(np.nan_to_num(pose[:, 3:]), axis=1) == 0)).sum())
    assert rep.dropouts == truth_drops > 0
    assert 28.0 < rep.rate_hz < 31.0  # the tracker's 30 Hz, not the recorder's 50
    assert rep.repeated > 0 and rep.outliers == 0
    assert 1000 * 0.01 * math.sqrt(3) * 0.8 < rep.jitter_mm < 1000 * 0.01 * math.sqrt(3) * 1.2
    assert np.diff(c.t).min() > 0.25 / 30  # no two readings microseconds apart are left
    # the kept readings are the tracker's frames: within the noise of the truth (3D, 4 sigma)
    err = np.linalg.norm(c.T_base_landmark[:, :3, 3] - _truth(c.t - 0.008), axis=1)
    assert np.sqrt((err ** 2).mean()) < 0.01 * math.sqrt(3) * 1.3


def test_the_old_check_on_recorder_stamps_would_have_called_this_jitter_impossible():
    """The speed over the recorder's 7 us stamps is thousands of m/s; over the tracker's period it is not."""
    t, pose, where, _ = _recorded(0)
    ok = np.isfinite(pose).all(1) & (np.linalg.norm(np.nan_to_num(pose[:, 3:]), axis=1) > 0.5)
    ok &= np.abs(pose[:, :3]).sum(1) > 0
    speed = np.linalg.norm(np.diff(pose[ok, :3], axis=0), axis=1) / np.diff(t[ok])
    assert speed.max() > 1000.0
    _clean(t, pose, where)  # imported


def test_smoothing_brings_the_track_closer_to_the_truth():
    t, pose, where, _ = _recorded(3, noise=0.015)
    raw, smooth = _clean(t, pose, where), _clean(t, pose, where, smooth=0.3)
    assert smooth.report.smoothed_s == 0.3 and raw.report.smoothed_s == 0.0

    def rms(c):
        return float(np.sqrt((np.linalg.norm(c.T_base_landmark[:, :3, 3] - _truth(c.t - 0.008), axis=1) ** 2).mean()))
    assert rms(smooth) < 0.6 * rms(raw)
    assert np.allclose(np.linalg.det(smooth.T_base_landmark[:, :3, :3]), 1.0)  # still rotations


def test_a_glitch_is_dropped_and_named_or_refused():
    t, pose, where, row = _recorded(4, glitch_at=1.5)
    c = _clean(t, pose, where)
    assert c.report.outliers == 1 and c.report.outlier_where == (row,)
    assert np.linalg.norm(c.T_base_landmark[:, :3, 3] - _truth(c.t - 0.008), axis=1).max() < 0.1
    with pytest.raises(RecordingError, match=rf"^hand.csv: row {row}: landmark 'hand': an impossible jump"):
        _clean(t, pose, where, outliers="refuse")


def test_a_landmark_that_jumps_and_stays_is_refused_not_cleaned():
    t, pose, where, _ = _recorded(5, drop=0.0)
    pose[len(t) // 2:, 1] += 0.8  # another person's hand from half-way on
    with pytest.raises(RecordingError, match=r"landmark 'hand': moves 0.8\d* m between rows \d+ and \d+ .*stays there"):
        _clean(t, pose, where)


def test_jitter_of_metres_is_refused_not_dropped_reading_by_reading():
    t, pose, where, _ = _recorded(6, noise=0.5, drop=0.0)
    with pytest.raises(RecordingError, match=r"of its \d+ readings jump .* not lone glitches"):
        _clean(t, pose, where)


def test_dropouts_refused_when_asked_naming_the_row():
    t, pose, where, _ = _recorded(7)
    first = int(np.flatnonzero(~np.isfinite(pose).all(1) | (np.linalg.norm(np.nan_to_num(pose[:, 3:]), axis=1) < 0.5)
                               | (np.nan_to_num(pose[:, :3]) == 0).all(1))[0])
    with pytest.raises(RecordingError, match=rf"^hand.csv: row {first + 2}: landmark 'hand': a dropout"):
        _clean(t, pose, where, dropouts="refuse")


def test_dropouts_longer_than_max_gap_are_refused():
    t, pose, where, _ = _recorded(8, drop=0.0)
    pose[(t > 1.0) & (t < 1.8)] = 0.0  # the track lost for 0.8 s
    with pytest.raises(RecordingError, match=r"a gap of 0.8\d* s .*missing readings bridged\), longer than --max-gap"):
        _clean(t, pose, where)
    assert _clean(t, pose, where, max_gap=1.0).report.longest_gap_s > 0.75


def test_jitter_estimate_is_the_noise_of_one_reading():
    rng = np.random.default_rng(0)
    t = np.sort(rng.uniform(0, 10, 600))
    for sigma in (0.001, 0.01, 0.03):
        x = _truth(t) + rng.normal(0, sigma, (len(t), 3))
        assert jitter_mm(t, x) == pytest.approx(1000 * sigma * math.sqrt(3), rel=0.1)
    assert jitter_mm(t, _truth(t)) < 0.5  # smooth motion alone: under half a millimetre


# -- the whole command on the shipped example and on broken files

def _cli(capsys, src, out, *extra):
    return run_cli(main, "lfd-import", [str(src), "--out", str(out), "--task", "handover", "--rate", "10",
                                        "--time-steps", "8", "--trim-pauses", "0.02", *extra], capsys)


def test_the_shipped_messy_recordings_import_with_the_defaults_and_say_what_was_done(tmp_path, capsys):
    r = _cli(capsys, DATA, tmp_path / "set")
    assert r.returncode == 0, r.stderr
    report = json.loads((tmp_path / "set" / "import_report.json").read_text())["demonstrations"]
    hand = [d["tracks"]["hand"] for d in report]
    assert all(x["dropouts"] > 0 and x["repeated"] > 0 for x in hand)
    assert all(28.0 < x["rate_hz"] < 31.0 for x in hand)  # make_recordings.py: 30 Hz
    assert all(14.0 < x["jitter_mm"] < 21.0 for x in hand)  # 1 cm per axis: 17.3 mm
    assert [x["outliers"] for x in hand] == [0, 0, 1, 0, 0]  # the one glitch, in demo_03
    line = next(x for x in r.stdout.splitlines() if x.startswith("  hand:"))
    assert "dropouts bridged" in line and "1 outliers dropped (demo_03 [" in line and "jitter" in line
    assert (tmp_path / "set" / "import.png").stat().st_size > 10_000
    r = _cli(capsys, DATA, tmp_path / "strict", "--dropouts", "refuse")
    assert r.returncode == 2 and "landmarks.csv: row" in r.stderr and "a dropout" in r.stderr, r.stderr
    r = _cli(capsys, DATA, tmp_path / "strict2", "--outliers", "refuse")
    assert r.returncode == 2 and "demo_03/landmarks.csv: row" in r.stderr and "impossible jump" in r.stderr, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["set"]  # nothing written on refusal


def test_a_missing_joint_reading_is_bridged_and_counted(tmp_path, capsys):
    src = tmp_path / "rec"
    shutil.copytree(DATA, src)
    path = src / "demo_02" / "joints.csv"
    rows = list(csv.reader(path.open()))
    rows[40][3], rows[41][1] = "", "nan"
    csv.writer(path.open("w", newline="")).writerows(rows)
    r = _cli(capsys, src, tmp_path / "set", "--no-plot")
    assert r.returncode == 0, r.stderr
    report = json.loads((tmp_path / "set" / "import_report.json").read_text())["demonstrations"]
    assert [d["joints"]["dropouts"] for d in report] == [0, 2, 0, 0, 0]
    assert "2 missing readings bridged" in r.stdout
    from lfd.io.recordings import read_csv_recording
    raw = read_csv_recording("demo_02", path, src / "demo_02" / "landmarks.csv", BAXTER_LEFT)
    with pytest.raises(RecordingError, match=r"joints.csv: row 41: a joint reading is missing"):
        clean_joints(raw.t, raw.q, raw.joint_where, raw.joint_source, "row", 0.5, dropouts="refuse")


def _rewrite(path: Path, fn) -> None:
    text = path.read_text()
    path.write_text(fn(text))


def _longer_row(d):
    _rewrite(d / "demo_02" / "joints.csv", lambda s: s.replace("\n", ",0.5\n", 30).replace(",0.5\n", "\n", 29))


BROKEN = [
    ("longer-row", _longer_row, "demo_02/joints.csv: row 30 has 18 fields, the header 17: more"),
    ("truncated-last-row", lambda d: _rewrite(d / "demo_04" / "joints.csv", lambda s: s.rstrip("\n")[:-40]),
     "demo_04/joints.csv: row"),
    ("joints-is-a-folder", lambda d: ((d / "demo_05" / "joints.csv").unlink(), (d / "demo_05" / "joints.csv").mkdir()),
     "demo_05/joints.csv: the joint recording is a folder, not a file"),
    ("symlink-loop", lambda d: ((d / "demo_05" / "joints.csv").unlink(),
                                os.symlink("joints.csv", d / "demo_05" / "joints.csv")),
     "demo_05/joints.csv: the joint recording"),
    ("txt-suffix", lambda d: (d / "demo_05" / "joints.csv").rename(d / "demo_05" / "joints.csv.txt"),
     "demo_05: a folder without a joints.csv (it holds: joints.csv.txt, landmarks.csv)"),
    ("landmarks-without-joints", lambda d: (d / "extra_landmarks.csv").write_text("time,name\n"),
     "extra_landmarks.csv: a landmark recording without its joint recording extra_joints.csv"),
]


@pytest.mark.parametrize("corrupt,fragment", [b[1:] for b in BROKEN], ids=[b[0] for b in BROKEN])
def test_a_broken_recording_is_refused_naming_file_and_row(tmp_path, capsys, corrupt, fragment):
    """Each was accepted before, the set written with the data changed (columns read by position,
    10 samples more) or with a demonstration left out, exit 0."""
    src = tmp_path / "rec"
    shutil.copytree(DATA, src)
    corrupt(src)
    r = _cli(capsys, src, tmp_path / "out")
    assert r.returncode == 2 and fragment in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec"]


def test_the_truncated_row_is_named_as_truncated(tmp_path):
    src = tmp_path / "rec"
    shutil.copytree(DATA, src)
    path = src / "demo_04" / "joints.csv"
    path.write_text(path.read_text().rstrip("\n")[:-40])
    n = len(path.read_text().splitlines())
    with pytest.raises(RecordingError, match=rf"joints.csv: row {n} has \d+ fields, the header 17: fewer \(a truncated"):
        import_recordings(src, BAXTER_LEFT, 10.0)


def test_files_on_clocks_that_disagree_are_named_as_such(tmp_path):
    src = tmp_path / "rec"
    shutil.copytree(DATA, src)
    path = src / "demo_02" / "landmarks.csv"
    rows = list(csv.reader(path.open()))
    rows[1:] = [[f"{float(r[0]) - 1000.0:.6f}", *r[1:]] for r in rows[1:]]  # stamped from 0, the joints from 1000
    csv.writer(path.open("w", newline="")).writerows(rows)
    with pytest.raises(RecordingError, match=r"demo_02/landmarks.csv: landmark 'hand' is read from .* the two files' "
                                             r"clocks disagree"):
        import_recordings(src, BAXTER_LEFT, 10.0)
