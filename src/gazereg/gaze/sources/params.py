"""Gaze-source parameters: one frozen dataclass per source, and the one conversion from command-line text.

Every source declares its parameters as a frozen dataclass deriving from `GazeSourceParams`, whose class
attribute `name` names the source; the value is passed typed everywhere (configs, the prior pipeline,
the experiment). Only a command line writes parameters as text, `key=value`, and `params_from_strings`
turns that into the dataclass once, naming an unknown key or a value of the wrong type (`UsageError`).
A parameters class checks its values in `__post_init__` and raises `UsageError` for one out of range.
"""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal, TypeVar

from gazereg.runtime.errors import UsageError


@dataclass(frozen=True)
class GazeSourceParams:
    """Base of every gaze source's parameters; `name` is the registered name of the source they build."""

    name: ClassVar[str] = ""


P = TypeVar("P", bound=GazeSourceParams)

_NONE_TEXT = ("none", "null")


def params_from_strings(cls: type[P], items: Sequence[str]) -> P:
    """`cls` from command-line `key=value` items (values read by the field's type: numbers, true/false,
    none/null for optional fields, a JSON list or comma-separated words for tuples); unknown keys and
    unreadable values are errors that say which."""
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    values: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep:
            raise UsageError(f"gaze source {cls.name!r}: parameter {item!r} must be key=value")
        if key not in names:
            raise UsageError(
                f"gaze source {cls.name!r} has no parameter {key!r}; its parameters: {', '.join(names) or 'none'}"
            )
        try:
            values[key] = _read(text, hints[key])
        except ValueError as e:
            raise UsageError(f"gaze source {cls.name!r}: bad value {key}={text!r}: {e}") from e
    try:
        return cls(**values)
    except ValueError as e:  # a value out of range (the parameters' own check)
        raise UsageError(f"gaze source {cls.name!r}: {e}") from e


def _read(text: str, kind: Any) -> Any:
    """`text` as a value of the type `kind` (the field's resolved annotation)."""
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin in (typing.Union, types.UnionType):
        if type(None) in args and text.strip().lower() in _NONE_TEXT:
            return None
        errors = []
        for option in (a for a in args if a is not type(None)):
            try:
                return _read(text, option)
            except ValueError as e:
                errors.append(str(e))
        raise ValueError("; ".join(errors))
    if origin is Literal:
        if text not in args:
            raise ValueError(f"choose one of {', '.join(map(str, args))}")
        return text
    if origin is tuple:
        words = json.loads(text) if text.lstrip().startswith("[") else [w for w in text.split(",") if w]
        return tuple(_read(str(w), args[0]) for w in words)
    if kind is bool:
        if text.lower() not in ("true", "false", "1", "0"):
            raise ValueError("expected true or false")
        return text.lower() in ("true", "1")
    if kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            raise ValueError(f"expected {'an integer' if kind is int else 'a number'}") from None
    if kind in (str, Path):
        return kind(text)
    raise TypeError(f"no command-line reading for parameters of type {kind!r}")
