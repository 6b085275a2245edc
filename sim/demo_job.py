"""``make demo``: the main job end to end on the built-in powder-transfer task.

1. ``python -m sim.demos`` makes 11 kinesthetic demonstrations (skipped when they exist);
2. ``train.py`` learns the task model of every compared variant (skipped when trained);
3. ``plan.py --evaluate`` runs the learned model, the arbitrary-landmark baseline and the
   learned model without obstacle avoidance on 10 seeded scenarios in PyBullet, prints the
   table and writes the results, TensorBoard logs and a GIF of a run. (All five of the paper's
   rows: ``python plan.py --evaluate --task powder --scenarios 10``; ~20 min here beside other jobs;
   these three keep ``make demo`` within 15 min on a 2-core machine: 8 min 53 s from a fresh
   clone, set-up included, with nothing else running.)
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
VARIANTS = ("learned+learned", "arbitrary+manual", "no-obstacle-avoidance")


def _run(args: list[str]) -> None:
    print("$ python " + " ".join(args), flush=True)
    subprocess.run([sys.executable, *args], cwd=ROOT, check=True)


def main() -> int:
    demos = ROOT / "runs" / "demos" / "powder"
    if not any(demos.glob("*.npz")):
        _run(["-m", "sim.demos", "--task", "powder", "--n", "11", "--seed", "0", "--out", str(demos)])
    _run(["plan.py", "--evaluate", "--task", "powder", "--scenarios", "10", "--workers", "2",
          "--variants", *VARIANTS, "--demos", str(demos), "--out", "runs/powder/eval",
          "--models", "runs/powder/models", "--video"])
    print("\nmake demo: done.\n"
          "  demonstrations:   runs/demos/powder/ (picture: docs/demos.png)\n"
          "  models:           runs/powder/models/<tool>-<env>/ (model.pt, config.json, summary.json)\n"
          "  TensorBoard:      .venv/bin/tensorboard --logdir runs/powder/models\n"
          "  results:          runs/powder/eval/results.json (per scenario: runs.jsonl)\n"
          "  videos:           runs/powder/eval/*.gif")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except subprocess.CalledProcessError as e:
        print(f"make demo: a stage failed with exit status {e.returncode}", file=sys.stderr)
        sys.exit(e.returncode or 1)
    except KeyboardInterrupt:
        print("make demo: interrupted; run it again to continue where it stopped", file=sys.stderr)
        sys.exit(130)
