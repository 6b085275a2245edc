"""``make demo`` (``python -m sim.demo_job``): the main job end to end on the built-in powder-transfer task.

1. ``sim.demos`` makes 11 kinesthetic demonstrations (skipped when they exist);
2. ``lfd-train`` learns the task model of every compared variant (skipped when trained);
3. ``lfd-plan --evaluate`` runs the learned model, the arbitrary-landmark baseline and the
   learned model without obstacle avoidance on 10 seeded scenarios in PyBullet, prints the
   table and writes the results, TensorBoard logs and a GIF of a run. (All five of the paper's
   rows: ``python plan.py --evaluate --task powder --scenarios 10``; ~20 min here beside other jobs;
   these three keep ``make demo`` within 15 min on a 2-core machine: 8 min 53 s from a fresh
   clone, set-up included, with nothing else running.)

Every stage is a library function called in this process (``sim.demos.main``,
``sim.plan_cli.main``, which trains missing models with ``lfd.train_cli.main``); outputs go to
``./runs`` in the current working directory (``make demo`` runs in the repository).
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

from lfd.cli import USER_ERRORS, error_line

VARIANTS = ("learned+learned", "arbitrary+manual", "no-obstacle-avoidance")


class StageFailed(RuntimeError):
    """A stage returned a non-zero exit status (its own message is already printed)."""

    def __init__(self, name: str, code: int):
        super().__init__(f"{name} failed with exit status {code}")
        self.code = code


def _run(name: str, main, argv: list[str]) -> None:
    print(f"$ {name} {shlex.join(argv)}", flush=True)
    code = int(main(argv) or 0)
    if code:
        raise StageFailed(name, code)


def main() -> int:
    from lfd.learning.demos import demo_files
    from sim import demos as demos_cli
    from sim import plan_cli

    runs = Path("runs")
    demos = runs / "demos" / "powder"
    if not demo_files(demos):
        _run("python -m sim.demos", demos_cli.main,
             ["--task", "powder", "--n", "11", "--seed", "0", "--out", str(demos)])
    _run("lfd-plan", plan_cli.main,
         ["--evaluate", "--task", "powder", "--scenarios", "10", "--workers", "2",
          "--variants", *VARIANTS, "--demos", str(demos), "--out", str(runs / "powder" / "eval"),
          "--models", str(runs / "powder" / "models"), "--video", "--resume"])
    print("\nmake demo: done.\n"
          "  demonstrations:   runs/demos/powder/ (picture: docs/demos.png)\n"
          "  models:           runs/powder/models/<tool>-<env>/ (model.pt, config.json, summary.json)\n"
          "  TensorBoard:      .venv/bin/tensorboard --logdir runs/powder/models\n"
          "  results:          runs/powder/eval/results.json (per scenario: runs.jsonl)\n"
          "  videos:           runs/powder/eval/*.gif")
    return 0


def cli() -> int:
    """Run ``main``; a failed stage, bad input or Ctrl-C ends with one line and its exit status."""
    try:
        return main()
    except StageFailed as e:
        print(f"make demo: {e}", file=sys.stderr)
        return e.code
    except USER_ERRORS() as e:
        print(f"make demo: error: {error_line(e)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("make demo: interrupted; run it again to continue where it stopped", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(cli())
