"""The base of the library's errors for bad input that a user can fix.

``lfd.learning.demoset.DemoFormatError``, ``lfd.robot.kinematics.KinematicsError``, ``lfd.learning.model.ModelFormatError``
and ``lfd.cli.UsageError`` derive from ``UserInputError``, so that the command-line tools
(``lfd.cli.run_main``) turn any of them into one line and exit status 2 without importing the
modules that raise them. A leaf module: it imports nothing from lfd.
"""

from __future__ import annotations

__all__ = ["UserInputError"]


class UserInputError(ValueError):
    """Bad input that the user can fix; the message says what and what would be right."""
