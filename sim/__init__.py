"""The PyBullet side of lfd: the simulated lab, collision checking, demonstrations, execution.

PyBullet writes a banner ("pybullet build time: ...") to the C-level stderr when imported
and chatter to stdout when loading URDFs; ``quiet_stdio`` silences both (file descriptors
1 and 2), so command-line tools can keep stderr to one clear line on errors. The modules that
need PyBullet take it from ``sim.bullet``, which imports it quietly; importing ``sim`` alone
does not load it, and ``require_pybullet`` names the extra to install when it is missing.
"""

from __future__ import annotations

import contextlib
import os
import sys

__all__ = ["quiet_stdio", "require_pybullet"]


@contextlib.contextmanager
def quiet_stdio():
    """Redirect the process's stdout and stderr file descriptors to /dev/null inside the block."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    saved = []
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        for fd in (1, 2):
            saved.append((fd, os.dup(fd)))
            os.dup2(devnull, fd)
        os.close(devnull)
    except OSError:  # no real file descriptors (embedded interpreters): stay loud
        pass
    try:
        yield
    finally:
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)


def require_pybullet() -> None:
    """Raise ``lfd.cli.UsageError`` naming the extra to install when PyBullet is missing."""
    import importlib.util

    if importlib.util.find_spec("pybullet") is None:
        from lfd.cli import UsageError
        raise UsageError("the simulator (lfd-plan, sim) needs PyBullet, which is not installed: "
                         "pip install \"lfd-landmarks[sim]\"")
