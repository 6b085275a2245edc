"""What every command-line entry point shares: one-line errors and exit status 2 for bad input.

Bad input (a broken demonstration file, an unknown option value, a folder that cannot be
written, a model that is not ours) is the user's to fix, so it gets one line on stderr that
names the problem and exit status 2 — never a traceback. Anything else is a bug and keeps its
traceback.

Output piped into a reader that stops early (``train.py --help | head -1``) ends quietly with
exit status 141 (``EXIT_BROKEN_PIPE`` = 128 + SIGPIPE), the status a shell reports for a Unix tool
killed by SIGPIPE (``yes | head -1``): under ``set -o pipefail`` the pipeline fails as it would
with any other tool, and the status is not 0 (the output was cut) nor 2 (the input was fine).
"""

from __future__ import annotations

import argparse
import errno
import os
import shlex
import shutil
import sys
from pathlib import Path

from lfd.errors import UserInputError, error_line

__all__ = [
    "EXIT_BROKEN_PIPE",
    "STORAGE_ERRNOS",
    "USER_ERRORS",
    "ArgumentParser",
    "DefaultsHelpFormatter",
    "UsageError",
    "check_device",
    "check_device_available",
    "check_seed",
    "error_line",
    "first_missing",
    "remove_created",
    "resume_command",
    "run_main",
    "writable_dir",
]

EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE: what a shell reports for a tool killed by a closed pipe
# writes the storage refused (disk full, quota, read-only file system, file too large): one line and
# status 1 (they were tracebacks); the writers leave no half-written file behind (atomic writes)
STORAGE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG})


class UsageError(UserInputError):
    """Bad input that the user can fix; the message says what and what would be right."""


def _user_errors() -> tuple[type[BaseException], ...]:
    """The errors a command reports as one line and exit status 2: every ``UserInputError``
    (bad demonstrations, a bad robot description or model file, a bad argument) and a missing or
    unreadable path."""
    return (UserInputError, FileNotFoundError, NotADirectoryError, PermissionError)


USER_ERRORS = _user_errors


class DefaultsHelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """``--help`` shows every option's default: ``(default: X)`` is added to a help text that does
    not already say its default in words (``default: ./runs/<task>``), ``(default: off)`` to a
    flag; required options and options without a default get nothing added."""

    def _get_help_string(self, action):
        text = action.help or ""
        if "%(default)" in text or "default" in text.lower() or action.default is argparse.SUPPRESS \
                or action.required or not action.option_strings:
            return text
        if action.nargs == 0 and isinstance(action.const, bool):  # a store_true / store_false flag
            return f"{text} (default: {'on' if action.default else 'off'})"
        if action.default is None:
            return text
        return f"{text} (default: %(default)s)"


class ArgumentParser(argparse.ArgumentParser):
    """An ``argparse`` parser whose errors are one line (no usage dump) and exit status 2.

    Options are taken only as spelled in ``--help`` (``allow_abbrev=False``): an abbreviation
    (``--scen``) would silently change meaning, or stop working, when an option is added.
    ``--help`` shows each option's default (``DefaultsHelpFormatter``)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        kwargs.setdefault("formatter_class", DefaultsHelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def path_arg(text: str) -> Path:
    """An ``argparse`` type for a file or folder option: ``Path(text)``, refusing an empty one
    (``Path("")`` is the current folder: ``--out ""`` wrote a model into it)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path; give a file or folder name")
    return Path(text)


def png_file(path: str | Path, what: str) -> Path:
    """``Path(path)`` when it names a ``.png`` file in an existing folder (checked before the
    work whose figure it will hold); ``UsageError`` otherwise."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise UsageError(f"{what} must name a .png file, got {str(path)!r}")
    if not path.parent.is_dir():
        raise UsageError(f"{what} {path}: folder {path.parent} does not exist")
    return path


def writable_dir(path: str | Path, what: str = "--out") -> Path:
    """Create ``path`` if needed and check it can be written; ``UsageError`` otherwise."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise UsageError(f"{what} {path}: exists and is not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except (OSError, FileExistsError) as e:
        raise UsageError(f"{what} {path}: cannot create this folder ({e.strerror or e})") from e
    if not os.access(path, os.W_OK | os.X_OK):
        raise UsageError(f"{what} {path}: folder is not writable")
    return path


def first_missing(path: Path) -> Path | None:
    """The outermost folder on the way to ``path`` that does not exist yet (what creating
    ``path`` makes), or None when ``path`` exists."""
    path = Path(os.path.abspath(path))
    missing = None
    for p in (path, *path.parents):
        if p.exists() or p.is_symlink():
            break
        missing = p
    return missing


def remove_created(out: Path, created: Path, keep: Path) -> None:
    """Remove a failed run's ``out`` and then each folder above it up to ``created`` (the outermost
    one the run made, ``first_missing``) while it is empty: what else was written there meanwhile
    (demonstrations generated into ``runs/demos`` when ``created`` is ``runs``) stays, and so does
    ``keep`` when it lies inside ``out`` (``lfd-train --out runs``: the demonstrations generated
    into ``runs/demos/<task>``)."""
    _remove_but(out, keep)
    for p in out.parents:
        if not p.is_relative_to(created):
            break
        try:
            p.rmdir()  # only when empty
        except OSError:
            break


def _remove_but(path: Path, keep: Path) -> None:
    """Remove ``path`` (a folder) with everything in it, except ``keep`` and the folders leading to it."""
    if not path.is_dir():
        return
    if not keep.is_relative_to(path):
        shutil.rmtree(path, ignore_errors=True)
        return
    if keep == path:
        return
    for child in path.iterdir():
        if keep.is_relative_to(child):
            _remove_but(child, keep)
        elif child.is_dir() and not child.is_symlink():
            shutil.rmtree(child, ignore_errors=True)
        else:
            child.unlink(missing_ok=True)


def resume_command(argv, prog: str, console: str) -> str:
    """The command line that resumes this run: its arguments (``argv``, else ``sys.argv``) with
    ``--resume``, after ``python SCRIPT.py`` when ``prog`` is a script run as such, else after the
    console script's name ``console``."""
    args = list(sys.argv[1:] if argv is None else argv)
    if "--resume" not in args:
        args.append("--resume")
    head = [sys.executable, sys.argv[0]] if prog.endswith(".py") and sys.argv[0].endswith(".py") else [console]
    return shlex.join([*head, *map(str, args)])


def run_main(main, argv=None, prog: str | None = None) -> None:
    """Run ``main(argv) -> int | None`` and exit; user errors become one line and status 2, a
    write the storage refused (``STORAGE_ERRNOS``) one line and status 1.

    A closed stdout (the reader of a pipe stopped) exits quietly with ``EXIT_BROKEN_PIPE``.
    """
    prog = prog or Path(sys.argv[0]).name
    try:
        try:
            code = int(main(argv) or 0)
        except SystemExit as e:  # argparse's own exit (--help, a bad argument): flushed below
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
        except KeyboardInterrupt:
            print(f"{prog}: interrupted", file=sys.stderr)
            code = 130
        except USER_ERRORS() as e:
            print(f"{prog}: error: {error_line(e)}", file=sys.stderr)
            code = 2
        except OSError as e:  # the machine's fault, not the input's: one line too, status 1
            if e.errno not in STORAGE_ERRNOS:
                raise
            print(f"{prog}: error: {error_line(e)}", file=sys.stderr)
            code = 1
        sys.stdout.flush()  # a closed pipe shows here, not as "Exception ignored" at shutdown
    except BrokenPipeError:
        _stdout_to_devnull()
        code = EXIT_BROKEN_PIPE
    sys.exit(code)


def _stdout_to_devnull() -> None:
    """Point stdout's file descriptor at /dev/null, so the interpreter's final flush of what is
    still buffered cannot fail again (the recipe of the ``signal`` module's documentation)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # no real stdout (embedded, captured): nothing to flush
        pass


def check_device(text: str) -> str:
    """``text`` if it names a torch device (``cpu``, ``cuda``, ``cuda:1``, ``mps``, ...);
    ``UsageError`` saying why otherwise. Whether this machine has it is checked before the fit."""
    import torch
    try:
        torch.device(text)
    except (RuntimeError, ValueError, TypeError) as e:
        raise UsageError(f"--device {text!r} is not a torch device string, e.g. cpu, cuda, cuda:1, mps "
                         f"(torch.device: {error_line(e)})") from None
    return text


def check_seed(value: int, option: str = "--seed") -> int:
    """``value`` if numpy and torch can both be seeded with it ([0, 2**63)), else a ``UsageError``."""
    if not 0 <= value < 2**63:
        raise UsageError(f"{option} must be in [0, 2**63), got {value}")
    return value


def check_task_name(text: str) -> str:
    """``text`` if it can name a task (``lfd.learning.tasks.TASK_NAME``), else a ``UsageError``."""
    from lfd.learning.tasks import TASK_NAME
    if not TASK_NAME.fullmatch(text):
        raise UsageError(f"--task must be a name of letters, digits, '_' and '-', got {text!r}")
    return text


def check_device_available(text: str) -> None:
    """``UsageError`` when this machine cannot put a tensor on the device ``text``."""
    from lfd.robot.device import usable_device
    try:
        usable_device(check_device(text), what="--device")
    except ValueError as e:
        raise UsageError(error_line(e)) from None
