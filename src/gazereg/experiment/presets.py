"""`gazereg presets`: every named preset of every kind, with the command that takes it and one line each.

    gazereg presets                      # all kinds
    gazereg presets --kind "evaluation budget"

A preset name means one thing: experiment presets keep their names (quick, smoke, paper, ...), the other
kinds have names of their own kind (training recipes `ci`, `cpu`, `tuned`, `gpu`; evaluation budgets such as
`clean-dim-noise-10`; collection budgets such as `demos-3x30`; policy sizes `tiny`, `large`; GLC sizes
`small`, `official`; GLC training recipes `scratch-small`, `finetune-official`). What the presets cost and what
they were sized from: docs/presets.md.
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from gazereg.envs import collect_config
from gazereg.evaluation import config as eval_config
from gazereg.experiment import config as experiment_config
from gazereg.experiment import pretrain_config
from gazereg.gaze.sources import glc as glc_source
from gazereg.policies.vla import configuration_vla
from gazereg.runtime.errors import UsageError
from gazereg.training import config as train_config
from gazereg.training import glc_cli

Factory = Callable[[], Any]


@dataclass(frozen=True)
class PresetKind:
    """One kind of preset: its name, where it is used, its presets by name, and the name its command takes
    without `--preset` (`default`; None: no command takes the kind by `--preset`)."""

    kind: str
    used_by: str
    presets: Callable[[], Mapping[str, Factory]]
    default: str | None = None


KINDS: tuple[PresetKind, ...] = (
    PresetKind(
        "experiment",
        "gazereg experiment / pool --preset (pool: required)",
        lambda: experiment_config.PRESETS,
        experiment_config.DEFAULT_PRESET,
    ),
    PresetKind(
        "training recipe", "gazereg train --preset", lambda: train_config.PRESETS, train_config.DEFAULT_PRESET
    ),
    PresetKind("evaluation budget", "gazereg eval --preset", eval_config.presets, eval_config.DEFAULT_PRESET),
    PresetKind(
        "collection budget",
        "gazereg collect --preset",
        lambda: collect_config.PRESETS,
        collect_config.DEFAULT_PRESET,
    ),
    PresetKind(
        "policy size", "gazereg.policies.vla.configuration_vla.PRESETS", lambda: configuration_vla.PRESETS
    ),
    PresetKind(
        "GLC size",
        "--glc.config, config= of the glc gaze source, gazereg glc eval --config",
        lambda: glc_source.CONFIGS,
    ),
    PresetKind(
        "GLC training recipe", "gazereg glc train --preset", glc_cli.train_presets, glc_cli.DEFAULT_PRESET
    ),
    PresetKind(
        "pretraining",
        "gazereg pretrain --preset",
        lambda: pretrain_config.PRESETS,
        pretrain_config.DEFAULT_PRESET,
    ),
)


def describe(factory: Factory, width: int = 110) -> str:
    """One line: the first sentence of the factory's docstring, cut at `width` characters."""
    doc = " ".join((factory.__doc__ or "").split())
    if not doc:
        return ""
    first = re.split(r"(?<=\.)\s", doc, maxsplit=1)[0]
    return first if len(first) <= width else first[: width - 3].rsplit(" ", 1)[0] + "..."


def catalogue(kinds: Sequence[PresetKind] = KINDS) -> list[tuple[PresetKind, str, str]]:
    """(kind, name, one-line description) of every preset, kind by kind, in each kind's order."""
    return [(k, name, describe(f)) for k in kinds for name, f in k.presets().items()]


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="gazereg presets", description=__doc__.split("\n\n")[0])
    ap.add_argument("--kind", help=f"only this kind: {', '.join(k.kind for k in KINDS)}")
    args = ap.parse_args(argv)
    kinds = KINDS
    if args.kind is not None:
        kinds = tuple(k for k in KINDS if k.kind == args.kind)
        if not kinds:
            raise UsageError(f"--kind {args.kind!r}: choose one of {', '.join(k.kind for k in KINDS)}")
    for kind in kinds:
        print(f"{kind.kind} ({kind.used_by}):")
        rows = catalogue((kind,))
        name_width = max(len(name) for _, name, _ in rows) + 1
        for _, name, line in rows:
            mark = "*" if name == kind.default else ""
            print(f"  {name + mark:<{name_width}}  {line}")
    print("* the command's default preset")
    return 0
