"""Gaze priors for an episode store: source -> per-frame heatmaps -> temporal aggregation -> disk.

    gazereg priors --store data/demos --source visuomotor --camera corner2
    gazereg priors --store data/demos --source glc --source-params checkpoint=runs/glc/final
    accelerate launch --num_processes 2 -m gazereg.gaze.priors --store ...   (episodes sharded by rank)

Priors are computed once, offline; training reads them and maps them onto its patch grid. Each run records
its source, parameters and aggregation in `priors/<name>/prior.json`; episodes already done are skipped, so
an interrupted run resumes, and a rerun with different settings under the same name is refused.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

from gazereg.data.store import EpisodeStore
from gazereg.gaze.aggregation import AggregationConfig, aggregate
from gazereg.gaze.sources import (
    GazeSource,
    GazeSourceParams,
    gaze_source_params,
    make_gaze_source,
    parse_source_params,
)
from gazereg.runtime.config import parse
from gazereg.runtime.version import __version__

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PriorsConfig:
    store: Path = Path("data/demos")
    """episode store to read and write priors into"""
    source: GazeSourceParams | str = "visuomotor"
    """the gaze source: its parameters (their class names the source), or a registered source's name for its
    default parameters"""
    name: str | None = None
    """prior name in the store (default: the source name)"""
    camera: str = "corner2"
    size: tuple[int, int] = (64, 64)
    """(h, w) of the stored heatmaps"""
    aggregation: AggregationConfig = field(default_factory=lambda: AggregationConfig(past=2, future=2))
    overwrite: bool = False
    """recompute every episode even if done (and accept changed settings)"""


@dataclass(frozen=True)
class PriorsCommand:
    """`gazereg priors`: `PriorsConfig` with the gaze source named and its parameters written as text."""

    store: Path = Path("data/demos")
    """episode store to read and write priors into"""
    source: str = "visuomotor"
    """gaze source: uniform | saliency | perturbed | recorded | visuomotor | glc | a registered plugin"""
    source_params: tuple[str, ...] = ()
    """source parameters as key=value (e.g. checkpoint=runs/glc/final stride=1)"""
    name: str | None = None
    """prior name in the store (default: the source name)"""
    camera: str = "corner2"
    size: tuple[int, int] = (64, 64)
    """(h, w) of the stored heatmaps"""
    aggregation: AggregationConfig = field(default_factory=lambda: AggregationConfig(past=2, future=2))
    overwrite: bool = False
    """recompute every episode even if done (and accept changed settings)"""

    def config(self) -> PriorsConfig:
        """The typed configuration; unknown source parameters and unreadable values are errors."""
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        del fields["source_params"]
        return PriorsConfig(**{**fields, "source": parse_source_params(self.source, self.source_params)})


def prior_record(source: GazeSource, cfg: PriorsConfig) -> dict[str, Any]:
    return {
        "source": source.describe(),
        "camera": cfg.camera,
        "size": list(cfg.size),
        "aggregation": dataclasses.asdict(cfg.aggregation),
        "gazereg_version": __version__,
    }


def make_priors(cfg: PriorsConfig, rank: int = 0, world: int = 1, progress: bool = True) -> str:
    """Compute and store priors for every episode of the store (this process's shard); returns the name."""
    store = EpisodeStore(cfg.store)
    params = cfg.source if isinstance(cfg.source, GazeSourceParams) else gaze_source_params(cfg.source)
    source = make_gaze_source(params)
    if hasattr(source, "bind"):
        source.bind(store)
    name = cfg.name or params.name
    record = prior_record(source, cfg)
    existing = store.prior_dir(name) / "prior.json"
    if existing.exists() and not cfg.overwrite:
        old = store.prior_info(name)
        if {k: old.get(k) for k in record if k != "gazereg_version"} != {
            k: v for k, v in record.items() if k != "gazereg_version"
        }:
            raise ValueError(
                f"priors {name!r} in {store.root} were made with other settings:\n  stored:    {old}\n  requested: {record}\n"
                "use --overwrite to recompute them or --name to store these separately"
            )
    if rank == 0:
        store.write_prior_info(name, record)
    todo = [
        i for i in store.indices() if i % world == rank and (cfg.overwrite or not store.has_prior(name, i))
    ]
    skipped = len(store.indices()) // max(world, 1) - len(todo)
    if skipped > 0:
        log.info("priors %s: %d episodes already done, skipping them", name, skipped)
    for i in tqdm(todo, desc=f"priors[{name}]", disable=not progress or not todo):
        ep = store.read(i, cameras=[cfg.camera])
        heat, valid = source(ep, cfg.camera, tuple(cfg.size))
        agg, ok = aggregate(heat, valid, cfg.aggregation)
        store.write_prior(name, i, agg.numpy(), ok.numpy())
    return name


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    command = parse(
        {"default": PriorsCommand},
        sys.argv[1:] if argv is None else argv,
        prog="gazereg priors",
        description=__doc__ or "",
    )
    try:
        cfg = command.config()
    except (KeyError, ValueError, TypeError) as e:
        print(f"gazereg priors: {e}", file=sys.stderr)
        return 2
    # `accelerate launch` / torchrun set these; each process takes every world-th episode (no sync needed).
    rank, world = int(os.environ.get("RANK", 0)), int(os.environ.get("WORLD_SIZE", 1))
    name = make_priors(cfg, rank=rank, world=world, progress=rank == 0)
    if rank == 0:
        print(f"priors {name!r} written to {Path(cfg.store) / 'priors' / name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
