"""``python train.py ...``: the ``lfd-train`` command (``lfd.train_cli``) run from a source checkout.

Learns a task model from demonstrations; ``python train.py --help`` lists every option.
"""

from __future__ import annotations

import functools

from lfd import train_cli
from lfd.cli import run_main

PROG = "train.py"
main = functools.partial(train_cli.main, prog=PROG)  # main(argv) -> exit status, as lfd-train's
parse_args = functools.partial(train_cli.parse_args, prog=PROG)

if __name__ == "__main__":
    run_main(main, prog=PROG)
