"""``python plan.py ...``: the ``lfd-plan`` command (``sim.plan_cli``) run from a source checkout.

Plans a learned task in a simulated scene, or evaluates every model variant (``--evaluate``);
``python plan.py --help`` lists every option.
"""

from __future__ import annotations

import functools

from lfd.cli import run_main
from sim import plan_cli

PROG = "plan.py"
main = functools.partial(plan_cli.main, prog=PROG)  # main(argv) -> exit status, as lfd-plan's
parse = functools.partial(plan_cli.parse, prog=PROG)

if __name__ == "__main__":
    run_main(main, prog=PROG)
