"""Named presets with dotted command-line overrides.

Every command has a frozen dataclass config and a dict of named presets (functions returning a config).
`parse` picks `--preset NAME` (default: the first preset) and applies `--a.b=value` overrides with tyro.
Resolved configs are stored as JSON beside what they produced.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
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


def parse(presets: dict[str, Callable[[], T]], argv: Sequence[str], prog: str, description: str = "") -> T:
    """Build the config: preset defaults, then dotted overrides from argv."""
    import tyro

    if not presets:
        raise ValueError("no presets defined")
    name, rest = split_preset(argv, default=next(iter(presets)))
    if name not in presets:
        raise SystemExit(f"unknown preset {name!r} for {prog}; choose one of {sorted(presets)}")
    base = presets[name]()
    doc = f"{description}\nPreset: {name} (choose with --preset; one of {', '.join(presets)})."
    return tyro.cli(type(base), default=base, args=rest, prog=prog, description=doc)


def to_dict(cfg: Any) -> dict[str, Any]:
    """A JSON-able dict of a (nested) dataclass config."""

    def convert(x: Any) -> Any:
        if isinstance(x, Path):
            return str(x)
        if isinstance(x, tuple | list):
            return [convert(v) for v in x]
        if isinstance(x, dict):
            return {k: convert(v) for k, v in x.items()}
        return x

    return convert(dataclasses.asdict(cfg))


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
