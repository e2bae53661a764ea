"""Named presets with dotted command-line overrides.

Every command has a frozen dataclass config and a dict of named presets (functions returning a config).
`parse` picks `--preset NAME` (default: the first preset) and applies `--a.b=value` overrides with tyro.
A field marked with `Choice` metadata holds one of several registered dataclasses: `--a.b.type NAME`
(LeRobot-style) swaps in the named class (its defaults) before the overrides of its fields apply, and
`to_dict` records the name as "type". Resolved configs are stored as JSON beside what they produced.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from gazereg.runtime.io import atomic_write_text

T = TypeVar("T")


def split_preset(argv: Sequence[str], default: str) -> tuple[str, list[str]]:
    """Remove `--preset NAME` / `--preset=NAME` from argv; returns (name, remaining args)."""
    rest: list[str] = []
    name = default
    it = iter(argv)
    for arg in it:
        if arg == "--preset":
            name = next(it, None)
            if name is None:
                raise SystemExit("--preset needs a name")
        elif arg.startswith("--preset="):
            name = arg.split("=", 1)[1]
        else:
            rest.append(arg)
    return name, rest


@dataclass(frozen=True)
class Choice:
    """Field metadata (`field(..., metadata=choice.metadata())`) of a config field whose dataclass is chosen
    by name: `lookup(name)` gives the class (KeyError naming the choices), `name_of(value)` a value's name."""

    lookup: Callable[[str], type]
    name_of: Callable[[Any], str]

    def metadata(self) -> dict[str, Choice]:
        return {CHOICE_KEY: self}


CHOICE_KEY = "gazereg.choice"


def _take_option(argv: list[str], flag: str) -> tuple[str | None, list[str]]:
    """Remove `flag VALUE` / `flag=VALUE` (underscores and dashes alike) from argv; returns (VALUE, rest)."""
    norm = flag.replace("_", "-")
    value, rest, it = None, [], iter(argv)
    for arg in it:
        key, eq, val = arg.partition("=")
        if key.replace("_", "-") != norm:
            rest.append(arg)
        elif eq:
            value = val
        else:
            value = next(it, None)
            if value is None:
                raise SystemExit(f"{flag} needs a name")
    return value, rest


def choose(cfg: T, argv: Sequence[str], prefix: str = "") -> tuple[T, list[str]]:
    """Apply the `--PATH.type NAME` options of `Choice` fields anywhere in a nested config: the field becomes
    the named class's default config (left as it is when it already is of that class). Returns the config
    and the remaining arguments."""
    rest, updates = list(argv), {}
    for f in dataclasses.fields(cfg):  # type: ignore[arg-type]
        value, path = getattr(cfg, f.name), f"{prefix}{f.name}"
        choice = f.metadata.get(CHOICE_KEY)
        if choice is not None:
            name, rest = _take_option(rest, f"--{path}.type")
            if name is not None:
                try:
                    cls = choice.lookup(name)
                except KeyError as e:
                    raise SystemExit(f"--{path}.type: {e.args[0]}") from None
                if type(value) is not cls:
                    value = updates[f.name] = cls()
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            chosen, rest = choose(value, rest, f"{path}.")
            if chosen is not value:
                updates[f.name] = chosen
    return (dataclasses.replace(cfg, **updates) if updates else cfg), rest  # type: ignore[type-var]


def parse(presets: dict[str, Callable[[], T]], argv: Sequence[str], prog: str, description: str = "") -> T:
    """Build the config: preset defaults, then dotted overrides from argv."""
    import tyro

    if not presets:
        raise ValueError("no presets defined")
    name, rest = split_preset(argv, default=next(iter(presets)))
    if name not in presets:
        raise SystemExit(f"unknown preset {name!r} for {prog}; choose one of {sorted(presets)}")
    base, rest = choose(presets[name](), rest)
    doc = f"{description}\nPreset: {name} (choose with --preset; one of {', '.join(presets)})."
    return tyro.cli(type(base), default=base, args=rest, prog=prog, description=doc)


def to_dict(cfg: Any) -> dict[str, Any]:
    """A JSON-able dict of a (nested) dataclass config; a `Choice` field's dict also holds its "type"."""

    def convert(x: Any) -> Any:
        if dataclasses.is_dataclass(x) and not isinstance(x, type):
            out = {}
            for f in dataclasses.fields(x):
                value = getattr(x, f.name)
                out[f.name] = convert(value)
                if CHOICE_KEY in f.metadata:
                    out[f.name] = {"type": f.metadata[CHOICE_KEY].name_of(value), **out[f.name]}
            return out
        if isinstance(x, Path):
            return str(x)
        if isinstance(x, tuple | list):
            return [convert(v) for v in x]
        if isinstance(x, dict):
            return {k: convert(v) for k, v in x.items()}
        return x

    return convert(cfg)


def save_config(cfg: Any, path: str | Path) -> None:
    atomic_write_text(Path(path), json.dumps(to_dict(cfg), indent=2, sort_keys=True) + "\n")


def config_diff(a: Any, b: Any, ignore: Sequence[str] = (), prefix: str = "") -> dict[str, list[Any]]:
    """{dotted.key: [value in a, value in b]} for every leaf where two saved configs (`to_dict`) differ,
    leaving out the dotted keys in `ignore`."""
    if isinstance(a, dict) and isinstance(b, dict):
        out: dict[str, list[Any]] = {}
        for k in sorted(set(a) | set(b)):
            if f"{prefix}{k}" not in ignore:
                out.update(config_diff(a.get(k), b.get(k), ignore, f"{prefix}{k}."))
        return out
    return {} if a == b else {prefix.rstrip("."): [a, b]}
