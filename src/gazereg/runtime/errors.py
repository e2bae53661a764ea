"""What a command-line user sees when something goes wrong: one line on stderr and an exit status.

    exit 2  bad usage: an option, a name or a path the user gave is wrong (`UsageError`, a missing path)
    exit 1  a failure: the command was used right but could not finish (bad data, a crash, a non-finite loss)

The traceback is printed only with `--verbose` (anywhere on the command line) or GAZEREG_DEBUG=1. Library code
raises ordinary exceptions; a user mistake raises `UsageError` (or a subclass) with a message that names the
option or file and what is wrong with it.
"""

from __future__ import annotations

import os
import sys
import traceback
from collections.abc import Callable

VERBOSE_FLAG = "--verbose"
DEBUG_ENV = "GAZEREG_DEBUG"


class UsageError(ValueError):
    """A user mistake: an option out of range, an unknown name, a path that is not what it should be."""


def exit_status(error: BaseException) -> int:
    """2 for bad usage (a `UsageError`, a path that does not exist), 1 for every other failure."""
    return 2 if isinstance(error, UsageError | FileNotFoundError | NotADirectoryError) else 1


def one_line(error: BaseException) -> str:
    """The error's message on one line (a KeyError's repr quotes are dropped)."""
    text = str(error.args[0]) if isinstance(error, KeyError) and error.args else str(error)
    text = " ".join(text.split()) or type(error).__name__
    return text if isinstance(error, UsageError | OSError | ValueError) else f"{type(error).__name__}: {text}"


def split_verbose(argv: list[str]) -> tuple[list[str], bool]:
    """argv without `--verbose`, and whether tracebacks are wanted (the flag or GAZEREG_DEBUG=1)."""
    verbose = VERBOSE_FLAG in argv or os.environ.get(DEBUG_ENV, "") not in ("", "0")
    return [a for a in argv if a != VERBOSE_FLAG], verbose


def report_errors(prog: str, entry: Callable[[list[str]], int | None], argv: list[str], verbose: bool) -> int:
    """Run `entry(argv)`; an exception becomes `prog: error: MESSAGE` on stderr and its exit status."""
    try:
        return int(entry(argv) or 0)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except Exception as e:
        if verbose:
            traceback.print_exc()
        status = exit_status(e)
        hint = "" if verbose or status == 2 else f" ({VERBOSE_FLAG} shows the traceback)"
        print(f"{prog}: error: {one_line(e)}{hint}", file=sys.stderr)
        return status
