"""The base of the library's errors for bad input that a user can fix.

``lfd.learning.demoset.DemoFormatError``, ``lfd.robot.kinematics.KinematicsError``, ``lfd.learning.model.ModelFormatError``
and ``lfd.cli.UsageError`` derive from ``UserInputError``, so that the command-line tools
(``lfd.cli.run_main``) turn any of them into one line and exit status 2 without importing the
modules that raise them. A leaf module: it imports nothing from lfd.
"""

from __future__ import annotations

__all__ = ["UserInputError", "error_line"]


class UserInputError(ValueError):
    """Bad input that the user can fix; the message says what and what would be right."""


def error_line(e: BaseException) -> str:
    """An error as one line: its message's first line (its type's name when it has none; an
    ``OSError``'s file name in front when the message lacks it). What ``lfd.cli.run_main``
    prints after ``"<prog>: error: "``."""
    msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    if isinstance(e, OSError) and e.filename and str(e.filename) not in msg:
        msg = f"{e.filename}: {msg}"
    return msg
