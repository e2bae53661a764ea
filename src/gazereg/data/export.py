"""`gazereg import export-priors`: a store's gaze priors out as a LeRobot sidecar.

    gazereg import export-priors --store STORE --prior NAME --out DIR [--episode-map 0=7 1=8]

Writes DIR/priors.parquet + DIR/priors.json (`gazereg.data.formats.lerobot_v3.export.export_priors_lerobot`)
and prints their paths as JSON.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from gazereg.data.errors import ExportUsageError
from gazereg.data.formats.lerobot_v3.export import export_priors_lerobot
from gazereg.runtime.config import parse


@dataclass(frozen=True)
class ExportPriorsConfig:
    store: Path = Path("data/demos")
    """episode store holding the priors"""
    prior: str = "recorded"
    """prior name in the store (priors/<name>/)"""
    out: Path = Path("gaze_priors")
    """output folder for priors.parquet + priors.json (suggested: <lerobot root>/gaze_priors/<prior>)"""
    episode_map: tuple[str, ...] = ()
    """optional store_index=episode_index pairs; default: the episode_index recorded at import (else the store index)"""


def parse_episode_map(items: Sequence[str]) -> dict[int, int] | None:
    """`("0=7", "1=8")` -> `{0: 7, 1: 8}` (store index -> LeRobot episode_index); None when empty."""
    if not items:
        return None
    try:
        return {int(a): int(b) for a, b in (p.split("=", 1) for p in items)}
    except ValueError as e:
        raise ExportUsageError(
            f"--episode-map entries must be store_index=episode_index, got {tuple(items)}"
        ) from e


def main(argv: list[str]) -> int:
    cfg = parse(
        {"default": ExportPriorsConfig},
        argv,
        prog="gazereg import export-priors",
        description="Export a store's gaze priors as a LeRobot sidecar (priors.parquet + priors.json).",
    )
    mapping = parse_episode_map(cfg.episode_map)
    path = export_priors_lerobot(cfg.store, cfg.prior, cfg.out, mapping, progress=True)
    print(json.dumps({"parquet": str(path), "info": str(path.with_suffix(".json"))}))
    return 0
