"""`gazereg import export-priors` and `gazereg import write-gaze`: a store's gaze priors out to LeRobot.

    gazereg import export-priors --store STORE --prior NAME --out DIR [--episode-map 0=7 1=8]
    gazereg import write-gaze --store STORE --prior NAME --root DATASET --out NEW_ROOT [--size 16 16]

`export-priors` writes a sidecar, DIR/priors.parquet + DIR/priors.json
(`gazereg.data.formats.lerobot_v3.export.export_priors_lerobot`), and prints their paths as JSON.
`write-gaze` writes a new version of the LeRobot v3.0 data set the store was imported from, with the prior as
the features gaze.<camera>.heatmap and gaze.<camera>.valid that `LeRobotDataset` loads
(`gazereg.data.formats.lerobot_v3.gaze_feature.write_gaze_dataset`), and prints a report as JSON.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from gazereg.data.errors import ExportUsageError
from gazereg.data.formats.lerobot_v3.export import export_priors_lerobot
from gazereg.data.formats.lerobot_v3.gaze_feature import write_gaze_dataset
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


@dataclass(frozen=True)
class WriteGazeConfig:
    store: Path = Path("data/demos")
    """episode store imported from the data set (gazereg import lerobot), holding the priors"""
    prior: str = "recorded"
    """prior name in the store (priors/<name>/)"""
    root: Path = Path("data/lerobot")
    """the LeRobot v3.0 data set the store was imported from (left unchanged)"""
    out: Path = Path("data/lerobot_gaze")
    """the new data set version to write (must not exist yet)"""
    size: tuple[int, ...] = ()
    """(h, w) of the written heatmaps; default: the prior's own size"""
    progress: bool = True


def write_gaze_main(argv: list[str]) -> int:
    cfg = parse(
        {"default": WriteGazeConfig},
        argv,
        prog="gazereg import write-gaze",
        description="Write a new version of a LeRobot v3.0 data set with a store's gaze priors as features "
        "gaze.<camera>.heatmap and gaze.<camera>.valid.",
    )
    if cfg.size and (len(cfg.size) != 2 or min(cfg.size) < 1):
        raise ExportUsageError(f"--size must be two positive integers h w, got {cfg.size}")
    size = (int(cfg.size[0]), int(cfg.size[1])) if cfg.size else None
    report = write_gaze_dataset(cfg.store, cfg.prior, cfg.root, cfg.out, size=size, progress=cfg.progress)
    print(json.dumps(report))
    return 0
