"""What a command-line user sees when something goes wrong: one line on stderr and an exit status.

    exit 2  bad usage: an option, a name or a path the user gave is wrong (`UsageError`, a missing path)
    exit 1  a failure: the command was used right but could not finish (bad data, a crash, a non-finite loss)

    exit 130  interrupted (Ctrl-C): `PROG: interrupted[ during WHAT][; ADVICE]`
    exit 143  terminated (SIGTERM): `PROG: terminated (SIGTERM)[ during WHAT][; ADVICE]`

The traceback is printed only with `--verbose` (anywhere on the command line) or GAZEREG_DEBUG=1. Library code
raises ordinary exceptions; a user mistake raises `UsageError` (or a subclass) with a message that names the
option or file and what is wrong with it.

While `report_errors` runs a command, SIGTERM raises `Terminated` in the main thread (a BaseException, like
KeyboardInterrupt), so `with` blocks and `finally` clauses run as the command unwinds: resumable work saves
its state and its clock (`gazereg.runtime.clock.ResumableClock`). Code that knows what was interrupted says so
with `annotate_interruption` (the experiment runner: the stage, and that rerunning resumes). A second SIGTERM
while unwinding ends the process at once, as SIGTERM's default does.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import traceback
from collections.abc import Callable, Iterator

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


class Terminated(BaseException):
    """SIGTERM arrived while a command ran (raised in the main thread by `sigterm_raises`)."""


TERMINATED_STATUS = 128 + signal.SIGTERM
INTERRUPTED_STATUS = 128 + signal.SIGINT


def annotate_interruption(error: BaseException, during: str, advice: str = "") -> None:
    """Say what an interruption (`Terminated`, KeyboardInterrupt) stopped, e.g. during="stage eval",
    advice="rerun the same command to resume"; the innermost annotation wins."""
    if not getattr(error, "gazereg_during", ""):
        error.gazereg_during = during  # type: ignore[attr-defined]
        error.gazereg_advice = advice  # type: ignore[attr-defined]


def interruption_line(prog: str, error: BaseException) -> str:
    """`PROG: terminated (SIGTERM) during stage eval; rerun the same command to resume` (or `interrupted`)."""
    what = "terminated (SIGTERM)" if isinstance(error, Terminated) else "interrupted"
    during, advice = getattr(error, "gazereg_during", ""), getattr(error, "gazereg_advice", "")
    return f"{prog}: {what}" + (f" during {during}" if during else "") + (f"; {advice}" if advice else "")


@contextlib.contextmanager
def sigterm_raises() -> Iterator[None]:
    """While the block runs in the main thread: SIGTERM raises `Terminated` there, once (a second SIGTERM
    gets the default action: the process ends). A process forked inside the block that inherited the handler
    ends on SIGTERM as by default. Elsewhere (another thread) the block runs unchanged."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    owner = os.getpid()

    def handler(signum: int, frame: object) -> None:
        signal.signal(signum, signal.SIG_DFL)
        if os.getpid() != owner:
            os.kill(os.getpid(), signum)
            return
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


def report_errors(prog: str, entry: Callable[[list[str]], int | None], argv: list[str], verbose: bool) -> int:
    """Run `entry(argv)`; an exception becomes `prog: error: MESSAGE` on stderr and its exit status, Ctrl-C
    and SIGTERM one line each (`interruption_line`) and exit 130 and 143."""
    try:
        with sigterm_raises():
            return int(entry(argv) or 0)
    except (KeyboardInterrupt, Terminated) as e:
        if verbose:
            traceback.print_exc()
        print(interruption_line(prog, e), file=sys.stderr)
        return TERMINATED_STATUS if isinstance(e, Terminated) else INTERRUPTED_STATUS
    except Exception as e:
        if verbose:
            traceback.print_exc()
        status = exit_status(e)
        hint = "" if verbose or status == 2 else f" ({VERBOSE_FLAG} shows the traceback)"
        print(f"{prog}: error: {one_line(e)}{hint}", file=sys.stderr)
        return status
