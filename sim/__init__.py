"""The PyBullet side of lfd: the simulated lab, collision checking, demonstrations, execution.

PyBullet writes a banner ("pybullet build time: ...") to the C-level stderr when imported
and chatter to stdout when loading URDFs; ``quiet_stdio`` silences both (file descriptors
1 and 2), so command-line tools can keep stderr to one clear line on errors.
"""

from __future__ import annotations

import contextlib
import os
import sys

__all__ = ["quiet_stdio"]


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


try:
    with quiet_stdio():
        import pybullet  # noqa: F401  (imported once, quietly; later imports are cached)
except ImportError as e:  # the plain install: the library (lfd) works, the simulator needs its extra
    raise ImportError(f"the simulator (sim, lfd-plan) needs PyBullet, which is not installed ({e}); "
                      f"install the package with its sim extra: pip install \"lfd-landmarks[sim]\"") from e
