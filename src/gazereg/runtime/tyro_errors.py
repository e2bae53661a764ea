"""What tyro refuses while it parses a command line, as one `UsageError` line naming the option.

    unknown option --train.stepz (did you mean --train.steps?)
    --steps must be an integer, got '2.5'
    --device must be one of auto, cpu, cuda, got 'gpu'

`gazereg.runtime.config.parse` wraps tyro in `tyro_errors_as_usage`; the gazereg CLI then prints the line and
exits 2 (`gazereg.runtime.errors`). Values tyro accepts are checked by the configs themselves (`Validated`).
"""

from __future__ import annotations

import contextlib
import difflib
import types
import typing
from collections.abc import Iterator, Sequence
from typing import Any

from gazereg.runtime.errors import UsageError


def closest_option(flag: str, known: Sequence[str]) -> str | None:
    """The known option `flag` was most likely meant as (a typo, or a dotted path one level off), or None."""
    norm = flag.replace("_", "-")
    match = difflib.get_close_matches(norm, known, n=1, cutoff=0.6)
    if match:
        return match[0]
    tail = norm.rpartition(".")[2].lstrip("-")
    by_tail = {k.rpartition(".")[2].lstrip("-"): k for k in reversed(known)}
    match = difflib.get_close_matches(tail, list(by_tail), n=1, cutoff=0.75)
    return by_tail[match[0]] if match else None


def given_values(argv: Sequence[str], flag: str) -> list[str]:
    """The values the last `flag VALUE ...` / `flag=VALUE` in argv gives (dashes and underscores alike)."""
    norm, values = flag.replace("_", "-"), []
    for i, arg in enumerate(argv):
        key, eq, val = arg.partition("=")
        if key.replace("_", "-") != norm:
            continue
        if eq:
            values = [val]
            continue
        values = []
        for nxt in argv[i + 1 :]:
            if nxt.startswith("--"):
                break
            values.append(nxt)
    return values


def _type_words(tp: Any) -> str | None:
    """What a value of annotation `tp` is, in words ("an integer", "numbers", ...); None if not simple."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        words = _type_words(inner[0]) if len(inner) == 1 else None
        return f"{words} or None" if words else None
    if origin in (tuple, list) and args:
        element = _type_words(args[0])
        plural = {"an integer": "integers", "a number": "numbers", "true or false": "true or false values"}
        return plural.get(element or "")
    return {int: "an integer", float: "a number", bool: "true or false"}.get(tp)


def tyro_event_error(event: Any, argv: Sequence[str], known: Sequence[str], prog: str) -> UsageError:
    """One `UsageError` line for a refusal of tyro's (`tyro._errors.ParseErrorEvent`): an unknown option
    with the closest known one, a value of the wrong type or outside a field's choices, naming the option."""
    from tyro import _errors as tyro_errors

    help_hint = f"`{prog} --help` lists the options"
    if isinstance(event, tyro_errors.UnrecognizedArgs):
        flags = [t.partition("=")[0] for t in event.tokens if t.startswith("-")]
        if not flags:
            return UsageError(f"unexpected argument {event.tokens[0]!r}: options are given as --name value")
        near = closest_option(flags[0], known)
        return UsageError(
            f"unknown option {flags[0]} " + (f"(did you mean {near}?)" if near else f"({help_hint})")
        )
    argument = getattr(event, "argument", None)
    name = argument.display_name() if argument is not None else None
    if isinstance(event, tyro_errors.InvalidChoice) and name:
        return UsageError(f"{name} must be one of {', '.join(event.choices)}, got {event.value!r}")
    if isinstance(event, tyro_errors.InstantiationFailure):
        if name is None:
            return UsageError(str(event.message))
        words = _type_words(argument.field.type_stripped)
        got = " ".join(given_values(argv, name))
        if words:
            return UsageError(f"{name} must be {words}, got {got!r}")
        return UsageError(f"{name}: {event.message}")
    if isinstance(event, tyro_errors.BadValue) and name:
        if event.offending_value is not None:
            return UsageError(f"{name} takes no value, got {event.offending_value!r}")
        return UsageError(f"{name} needs {argument.lowered.nargs} value(s)")
    if isinstance(event, tyro_errors.MissingArgs):
        names = ", ".join(a.arg.display_name() for a in event.missing_arguments)
        return UsageError(f"missing option(s): {names}")
    return UsageError(f"the command line was refused ({type(event).__name__}); {help_hint}")


@contextlib.contextmanager
def tyro_errors_as_usage(known: Sequence[str], argv: Sequence[str], prog: str) -> Iterator[None]:
    """While tyro parses `argv` for `prog`: its refusals become one `UsageError` line (`tyro_event_error`;
    `known`: the options the command takes, for "did you mean") instead of its box. The hook is tyro's
    private `tyro._errors.on_parse_error` (tyro 1.0.17, constraints.txt); without it tyro's box stays."""
    try:
        from tyro._errors import on_parse_error
    except ImportError:  # another tyro: its own box
        yield
        return

    def hook(event: Any) -> None:
        raise tyro_event_error(event, argv, known, prog)

    with on_parse_error(hook):
        yield
