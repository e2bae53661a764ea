"""Named presets with dotted command-line overrides.

Every command has a frozen dataclass config and a dict of named presets (functions returning a config).
`parse` picks `--preset NAME` (default: the command's named default) and applies `--a.b=value` overrides with tyro.
A field marked with `Choice` metadata holds one of several registered dataclasses: `--a.b.type NAME`
(LeRobot-style) swaps in the named class (its defaults) before the overrides of its fields apply, and
`to_dict` records the name as "type". Resolved configs are stored as JSON beside what they produced.

Validation: a config class derived from `Validated` checks its own fields in `validate` whenever it is built
(`__post_init__`: presets, `dataclasses.replace`, the command line) and raises `UsageError` naming the option
as it is typed (`--gaze.weight must be a finite number >= 0, got nan`; `require_number`, `require_choice`).
While `parse` runs tyro the checks wait until the whole config is built, then run with each option's full
dotted path, so a bad value ends as one error line (not tyro's box); what tyro itself refuses (an unknown
option, a value of the wrong type) is one line too (`gazereg.runtime.tyro_errors`).

Resuming: `check_same_config` refuses to continue a folder made with another configuration, listing every
changed key (`optim.lr: 0.001 -> 0.002`) except the execution-only keys that the caller allows to change.
"""

from __future__ import annotations

import contextvars
import dataclasses
import json
import math
import numbers
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, TypeVar

from gazereg.runtime.errors import UsageError
from gazereg.runtime.io import atomic_write_text
from gazereg.runtime.tyro_errors import tyro_errors_as_usage

T = TypeVar("T")


def split_preset(argv: Sequence[str], default: str | None) -> tuple[str | None, list[str]]:
    """Remove `--preset NAME` / `--preset=NAME` from argv; returns (name, remaining args). Without the flag
    the name is `default` (None for a command that has none)."""
    rest: list[str] = []
    name = default
    it = iter(argv)
    for arg in it:
        if arg == "--preset":
            name = next(it, None)
            if name is None:
                raise UsageError("--preset needs a name")
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
                raise UsageError(f"{flag} needs a name")
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
                    raise UsageError(f"--{path}.type: {e.args[0]}") from None
                if type(value) is not cls:
                    value = updates[f.name] = cls()
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            chosen, rest = choose(value, rest, f"{path}.")
            if chosen is not value:
                updates[f.name] = chosen
    return (dataclasses.replace(cfg, **updates) if updates else cfg), rest  # type: ignore[type-var]


def parse_named(
    presets: dict[str, Callable[[], T]],
    argv: Sequence[str],
    prog: str,
    description: str = "",
    default: str | None = None,
    required: bool = False,
) -> tuple[str, T]:
    """(the preset's name, the config): preset defaults, then dotted overrides from argv. Without `--preset`
    the preset is `default` (a registry of one preset is its own default; the order of several never chooses);
    `required`, or several presets and no `default`, refuses (UsageError) an argv without `--preset`, except
    `--help`: the command's description and its presets, exit 0."""
    import tyro

    if not presets:
        raise ValueError("no presets defined")
    if default is None and len(presets) == 1:
        default = next(iter(presets))
    name, rest = split_preset(argv, default=None if required else default)
    if name is None:
        if "-h" in rest or "--help" in rest:  # help before the preset it needs: the command, then its presets
            print(f"usage: {prog} --preset NAME [OPTIONS]\n\n{description}\nPresets: {', '.join(presets)}.")
            print(f"`{prog} --preset NAME --help` lists the options and that preset's values.")
            raise SystemExit(0)
        raise UsageError("--preset NAME is required")
    if name not in presets:
        raise UsageError(f"unknown preset {name!r} for {prog}; choose one of {sorted(presets)}")
    base, rest = choose(presets[name](), rest)
    doc = f"{description}\nPreset: {name} (choose with --preset; one of {', '.join(presets)})."
    token = _DEFER_VALIDATION.set(True)
    try:
        with tyro_errors_as_usage(known_options(base), rest, prog):
            cfg = tyro.cli(type(base), default=base, args=rest, prog=prog, description=doc)
    finally:
        _DEFER_VALIDATION.reset(token)
    validate_tree(cfg)
    return name, cfg


def parse(
    presets: dict[str, Callable[[], T]],
    argv: Sequence[str],
    prog: str,
    description: str = "",
    default: str | None = None,
) -> T:
    """The config of `parse_named` (for commands that do not record their preset's name)."""
    return parse_named(presets, argv, prog, description, default)[1]


# ----- tyro's refusals as one line ------------------------------------------------------------------------
def known_options(cfg: Any, prefix: str = "") -> list[str]:
    """Every option a (nested) dataclass config takes on the command line, as typed (`--train.batch-size`,
    booleans also as `--no-NAME`, a `Choice` field's `--PATH.type`), plus `--preset` and `--help`."""
    out = [] if prefix else ["--preset", "--help"]
    for f in dataclasses.fields(cfg):
        value, path = getattr(cfg, f.name), prefix + f.name
        if CHOICE_KEY in f.metadata:
            out.append(option(path + ".type"))
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            out += known_options(value, path + ".")
        elif isinstance(value, bool):
            out += [option(path), "--" + (prefix + "no-" + f.name).replace("_", "-")]
        else:
            out.append(option(path))
    return out


# ----- validation -----------------------------------------------------------------------------------------
_DEFER_VALIDATION: contextvars.ContextVar[bool] = contextvars.ContextVar(
    "gazereg_defer_validation", default=False
)


def option(path: str) -> str:
    """The command-line spelling of a dotted config path: `optim.min_lr_frac` -> `--optim.min-lr-frac`."""
    return "--" + path.replace("_", "-")


class Validated:
    """Base of a frozen dataclass config that checks its fields when built. Subclasses implement
    `validate(prefix)`, naming options as `option(prefix + field)`; `OPTION_PREFIX` is the prefix used when the
    config is built on its own (e.g. "gaze." for the `gaze` field of the training config)."""

    OPTION_PREFIX: ClassVar[str] = ""

    def __post_init__(self) -> None:
        if not _DEFER_VALIDATION.get():
            self.validate(self.OPTION_PREFIX)

    def validate(self, prefix: str) -> None:
        """Raise `UsageError` naming the first option out of range."""


def validate_tree(cfg: Any, prefix: str = "") -> None:
    """Run `validate` on every `Validated` config in a nested config, innermost first, with full paths."""
    if not dataclasses.is_dataclass(cfg) or isinstance(cfg, type):
        return
    for f in dataclasses.fields(cfg):
        validate_tree(getattr(cfg, f.name), f"{prefix}{f.name}.")
    if isinstance(cfg, Validated):
        cfg.validate(prefix)


def _bounds_text(low: float | None, high: float | None, open_low: bool, open_high: bool) -> str:
    if low is not None and high is not None:
        return f" in {'(' if open_low else '['}{low:g}, {high:g}{')' if open_high else ']'}"
    if low is not None:
        return f" {'>' if open_low else '>='} {low:g}"
    if high is not None:
        return f" {'<' if open_high else '<='} {high:g}"
    return ""


def require_number(
    value: Any,
    path: str,
    low: float | None = None,
    high: float | None = None,
    *,
    integer: bool = False,
    open_low: bool = False,
    open_high: bool = False,
) -> None:
    """Raise `UsageError` naming `option(path)` unless `value` is a finite number (an integer with `integer`)
    within [low, high] (either end open with `open_low` / `open_high`, either omitted for no bound)."""
    kind = numbers.Integral if integer else numbers.Real
    ok = isinstance(value, kind) and not isinstance(value, bool) and math.isfinite(value)
    if ok and low is not None:
        ok = value > low if open_low else value >= low
    if ok and high is not None:
        ok = value < high if open_high else value <= high
    if not ok:
        what = "an integer" if integer else "a finite number"
        raise UsageError(
            f"{option(path)} must be {what}{_bounds_text(low, high, open_low, open_high)}, got {value!r}"
        )


def require_entries(
    values: Iterable[Any],
    path: str,
    *,
    non_empty: bool = True,
    noun: str = "",
    show: Callable[[Any], str] = repr,
    error: type[UsageError] = UsageError,
) -> None:
    """Raise `error` naming `option(path)` when a list option is empty (with `non_empty`; "give at least one
    NOUN") or lists an entry more than once (entries written with `show`)."""
    values = tuple(values)
    if non_empty and not values:
        raise error(f"{option(path)} is empty: give at least one{' ' + noun if noun else ''}")
    twice = sorted({show(v) for v in values if values.count(v) > 1})
    if twice:
        raise error(f"{option(path)} lists {', '.join(twice)} more than once")


def require_choice(value: Any, path: str, choices: Iterable[Any]) -> None:
    """Raise `UsageError` naming `option(path)` unless `value` is one of `choices`."""
    allowed = list(choices)
    if value not in allowed:
        raise UsageError(f"{option(path)} must be one of {', '.join(map(str, allowed))}, got {value!r}")


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


class ConfigMismatch(UsageError):
    """A folder holds work made with another configuration than the one given (`check_same_config`)."""


def check_same_config(
    saved: Mapping[str, Any], new: Any, execution_keys: Collection[str], where: str | Path, advice: str
) -> None:
    """Refuse to continue work saved with another configuration.

    saved: the saved config (`to_dict` as JSON); new: the config now given (a config or its `to_dict`);
    execution_keys: dotted keys that change how the work runs, not its results (they may differ);
    where: the folder or file that holds the saved work; advice: what the user can do, ending the message.
    Raises `ConfigMismatch` listing every other changed key as `key: old -> new`.
    """
    new_dict = new if isinstance(new, Mapping) else to_dict(new)
    diff = config_diff(json.loads(json.dumps(saved)), json.loads(json.dumps(new_dict)), tuple(execution_keys))
    if diff:
        changes = ", ".join(f"{k}: {a!r} -> {b!r}" for k, (a, b) in diff.items())
        raise ConfigMismatch(f"{where} holds a run with another configuration ({changes}); {advice}")
