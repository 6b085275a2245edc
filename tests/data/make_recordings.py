"""Write ``tests/data/recordings``: a small recorded-looking set of handover demonstrations.

Made by the project (no real recording is shipped): ``lfd.learning.synthetic.make_synthetic``
with a hand that travels 0.4 m during each demonstration (the task point meets it), then
written as a Baxter SDK joint recorder and a tracker would: joints at ~50 Hz with timing jitter,
noise, dropped rows and pauses at both ends, in ``time,left_s0,...,right_w2,right_gripper``
columns; the hand tracked by a skeleton tracker at 30 Hz and written as a recorder does
(``_tracker_rows``: stamped with the recorder's clock, repeats, new readings microseconds after a
repeat, all-zero dropouts, about 1 cm of jitter per axis, one glitch), the two other landmarks
(a head, a table marker) read once, as ``time,name,x,y,z,qx,qy,qz,qw`` rows. Run ``python tests/data/make_recordings.py``
to write it again (deterministic).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from lfd.learning.synthetic import make_synthetic
from lfd.robot.kinematics import KinematicModel

OUT = Path(__file__).resolve().parent / "recordings"
NAMES = ("hand", "head", "table_marker")
JOINTS = ("s0", "s1", "e0", "e1", "w0", "w1", "w2")
HEADER = ["time", *(f"left_{j}" for j in JOINTS), "left_gripper", *(f"right_{j}" for j in JOINTS), "right_gripper"]


def main() -> None:
    rng = np.random.default_rng(7)
    ds, truth = make_synthetic(KinematicModel.from_spec(), n_demos=5, time_steps=8, Z=3, seed=0,
                               landmark_motion=0.4, samples_per_step=(5, 8))
    for m, d in enumerate(ds.demos):
        folder = OUT / f"demo_{m + 1:02d}"
        folder.mkdir(parents=True, exist_ok=True)
        t_demo = np.arange(d.n_samples) * d.dt  # the demonstration's own clock, s
        pause = 1.0  # s held still before and after
        t = np.arange(0.0, t_demo[-1] + 2 * pause, 0.02) + rng.uniform(-0.004, 0.004)  # ~50 Hz
        t = np.sort(t + rng.uniform(-0.003, 0.003, len(t)))
        keep = rng.random(len(t)) > 0.03  # 3% of the rows dropped
        t = t[keep]
        tc = np.clip(t - pause, 0.0, t_demo[-1])
        q = np.stack([np.interp(tc, t_demo, d.q[:, j]) for j in range(7)], axis=1)
        q += rng.normal(0, 0.002, q.shape)
        right = np.tile([0.3, -0.5, 0.0, 1.2, 0.0, 0.8, 0.0], (len(t), 1))
        with (folder / "joints.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(HEADER)
            for k in range(len(t)):
                w.writerow([f"{t[k] + 1000.0:.4f}", *(f"{x:.5f}" for x in q[k]), "100.0",
                            *(f"{x:.5f}" for x in right[k]), "0.0"])
        lm = d.landmarks  # (S, Z, 4, 4), the hand (index 0) tracked
        rows = _tracker_rows(rng, t + 1000.0, lm, t_demo, pause, glitch=(m == 2))
        with (folder / "landmarks.csv").open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["time", "name", "x", "y", "z", "qx", "qy", "qz", "qw"])
            w.writerows(rows)
    (OUT / "TRUTH.txt").write_text(f"tool point (gripper frame, m): {np.round(truth.tool, 4).tolist()}\n"
                                   "the task point meets the landmark 'hand'\n")


def _tracker_rows(rng, recorder_t, lm, t_demo, pause, glitch: bool) -> list[list[str]]:
    """The landmark CSV's rows as a recorder writes them: the hand from a skeleton tracker at
    30 Hz with about 1 cm of jitter per axis, each recorder row (``recorder_t``, ~50 Hz) stamped
    with the recorder's clock and holding the tracker's latest reading (repeats), a new reading
    often written 7 us after a repeat of the old one, 3% of the rows all-zero dropouts (some in
    bursts), and with ``glitch`` one tracker frame 0.6 m off (another person's hand); the head
    and the table marker read once."""
    tt = np.arange(recorder_t[0] - 1000.0 - 0.05, recorder_t[-1] - 1000.0 + 0.05, 1 / 30)  # the tracker's frames
    tcl = np.clip(tt - pause, 0.0, t_demo[-1])
    pos = np.stack([np.interp(tcl, t_demo, lm[:, 0, i, 3]) for i in range(3)], axis=1)
    pos += rng.normal(0, 0.01, pos.shape)
    if glitch:
        pos[len(pos) // 2] += [0.0, 0.6, 0.0]
    quat = Rotation.from_matrix(lm[0, 0, :3, :3]).as_quat()
    arrival = tt + 1000.0 + rng.uniform(0.004, 0.012, len(tt))  # when each frame reaches the recorder
    drop = rng.random(len(recorder_t)) < 0.02
    for start in rng.choice(len(recorder_t) - 5, 2, replace=False):  # two bursts of a lost track
        drop[start:start + 4] = True

    def row(stamp, k):
        return [f"{stamp:.6f}", "hand", *(f"{x:.5f}" for x in pos[k]), *(f"{x:.6f}" for x in quat)]

    out, last = [], -1
    for j, r in enumerate(recorder_t):
        k = int(np.searchsorted(arrival, r, side="right")) - 1  # the newest frame arrived by now
        if k < 0:
            continue
        if drop[j]:
            out.append([f"{r:.6f}", "hand", *["0.0"] * 7])
        elif k != last and last >= 0 and rng.random() < 0.5:  # the old reading, then the new one 7 us later
            out.append(row(r, last))
            out.append(row(r + 7e-6, k))
        else:
            out.append(row(r, k))
        last = k
    for z, name in ((1, "head"), (2, "table_marker")):
        q = Rotation.from_matrix(lm[0, z, :3, :3]).as_quat()
        out.append(["1000.000000", name, *(f"{x:.5f}" for x in lm[0, z, :3, 3]), *(f"{x:.6f}" for x in q)])
    return out


if __name__ == "__main__":
    main()
