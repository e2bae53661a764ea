"""Gaze priors for an episode store: source -> per-frame heatmaps -> temporal aggregation -> disk.

    gazereg priors --store data/demos --source visuomotor --camera corner2
    gazereg priors --store data/demos --source glc --source-params checkpoint=runs/glc/final
    accelerate launch --num_processes 2 -m gazereg.gaze.priors --store ...   (episodes sharded by rank)

Priors are computed once, offline; training reads them and maps them onto its patch grid. The inputs (the
source and its parameters, the camera, the size) are checked before anything is written. A run records its
source, parameters and aggregation in `priors/<name>/prior.pending.json` while it works and in the manifest
`priors/<name>/prior.json` once every episode of the store has its prior (the manifest is written last, so a
failed run leaves no manifest behind). Episodes already done are skipped, so an interrupted run resumes, and a
rerun with different settings under the same name is refused while files made with the old ones exist.

The record holds the camera and its frame size (`image_hw`, (H, W) pixels), which training checks against the
camera it regularizes, and a `settings_fingerprint` (16 hex digits of the SHA-256 of the settings) that every
prior file records too; the manifest is written only when every file has it, and readers refuse a file
without it (gazereg.data.store). One run writes a prior at a time: a run holds an exclusive lock on
`priors/<name>/.writing.lock` (flock; its pid written in it, released however the run ends) and a second run
on the same name is refused in one line naming the holder's pid. The processes of one sharded run share that
lock and each holds its own `.writing.rankR.lock`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import sys
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gazereg.aggregation import AggregationConfig, aggregate
from gazereg.data.store import PRIOR_MANIFEST, EpisodeStore
from gazereg.gaze.sources import (
    GazeSource,
    GazeSourceParams,
    gaze_source_params,
    make_gaze_source,
    parse_source_params,
)
from gazereg.runtime.config import parse
from gazereg.runtime.errors import UsageError, report_errors, split_verbose
from gazereg.runtime.io import LockHeld, file_lock, sweep_stale_temps
from gazereg.runtime.progress import Progress
from gazereg.runtime.version import __version__

log = logging.getLogger(__name__)

LOCK_FILE = ".writing.lock"
DERIVED = ("gazereg_version", "settings_fingerprint", "image_hw")
"""record keys that are not settings of their own (the fingerprint and the frame size follow from the rest
and the store); a manifest written before they were recorded does not differ for lacking them"""


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


def settings_fingerprint(record: dict[str, Any]) -> str:
    """16 hex digits of the SHA-256 of a prior record's settings (source, camera, size, aggregation)."""
    settings = {k: v for k, v in record.items() if k not in DERIVED}
    return hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:16]


def camera_size(store: EpisodeStore, camera: str) -> list[int] | None:
    """[H, W] of `camera`'s frames when every episode of the store has that size, else None."""
    sizes = {tuple(store.meta(i)["cameras"][camera]) for i in store.indices()}
    return list(sizes.pop()) if len(sizes) == 1 else None


def prior_record(source: GazeSource, cfg: PriorsConfig, image_hw: list[int] | None = None) -> dict[str, Any]:
    """The manifest of a prior: its settings, the frame size (H, W) of the camera it was made on, the settings
    fingerprint every file records and the version."""
    record: dict[str, Any] = {
        "source": source.describe(),
        "camera": cfg.camera,
        "size": list(cfg.size),
        "aggregation": dataclasses.asdict(cfg.aggregation),
        "image_hw": image_hw,
        "gazereg_version": __version__,
    }
    record["settings_fingerprint"] = settings_fingerprint(record)
    return record


def _settings_differ(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """The settings (keys of `new`, the version and the fingerprint aside) whose stored value is not the
    requested one; a frame size an older record lacks does not count."""
    return [
        k
        for k in new
        if k not in ("gazereg_version", "settings_fingerprint")
        and old.get(k) != new[k]
        and not (k in DERIVED and k not in old)
    ]


@contextmanager
def writer_lock(store: EpisodeStore, name: str, rank: int = 0, world: int = 1) -> Iterator[None]:
    """Hold the prior's writer lock (module docstring) for the block; a `UsageError` naming the holder's pid
    when another run holds it."""
    folder = store.prior_dir(name)
    locks = [(folder / LOCK_FILE, world > 1)]
    if world > 1:
        locks.append((folder / f".writing.rank{rank}.lock", False))
    with ExitStack() as stack:
        for path, shared in locks:
            try:
                stack.enter_context(file_lock(path, shared=shared))
            except LockHeld as e:
                who = f"process {e.holder}" if e.holder else "another process"
                raise UsageError(
                    f"priors {name!r} in {store.root} are being written by another `gazereg priors` run "
                    f"({who} holds {path}); wait for it to finish, or use --name to store these separately"
                ) from None
        yield


def check_inputs(store: EpisodeStore, cfg: PriorsConfig) -> None:
    """Refuse (`UsageError`, before anything is written) an empty store, a camera some episode lacks and a bad
    size."""
    if not store.indices():
        raise UsageError(f"store {store.root} has no episodes to make priors for")
    if len(cfg.size) != 2 or min(cfg.size) < 1:
        raise UsageError(f"--size must be two positive numbers (h, w), got {tuple(cfg.size)}")
    for i in store.indices():
        cameras = store.meta(i)["cameras"]
        if cfg.camera not in cameras:
            raise UsageError(
                f"--camera {cfg.camera!r}: episode {i} of store {store.root} has no such camera; "
                f"it has {', '.join(sorted(cameras))}"
            )


def check_settings(store: EpisodeStore, cfg: PriorsConfig, name: str, record: dict[str, Any]) -> None:
    """Refuse (`UsageError`) settings that differ from those the prior's existing files were made with (unless
    overwrite)."""
    old = store.prior_record(name)
    if old is None or cfg.overwrite or not store.prior_indices(name):
        return
    differ = _settings_differ(old, record)
    if differ:
        shown = "; ".join(f"{k}: stored {old.get(k)!r}, requested {record[k]!r}" for k in differ)
        raise UsageError(
            f"priors {name!r} in {store.root} were made with other settings ({shown}); use --overwrite to "
            "recompute them or --name to store these separately"
        )


def make_priors(cfg: PriorsConfig, rank: int = 0, world: int = 1, progress: bool = True) -> str:
    """Compute and store priors for every episode of the store (this process's shard); returns the name.
    `progress`: episodes done of this run's, with the rate and ETA, on stderr (`gazereg.runtime.progress`).

    The process that finds every episode done writes the manifest (prior.json), last."""
    store = EpisodeStore(cfg.store)
    params = cfg.source if isinstance(cfg.source, GazeSourceParams) else gaze_source_params(cfg.source)
    source = make_gaze_source(params)
    if hasattr(source, "bind"):
        source.bind(store)
    name = cfg.name or params.name
    check_inputs(store, cfg)
    record = prior_record(source, cfg, camera_size(store, cfg.camera))
    with writer_lock(store, name, rank, world):
        check_settings(store, cfg, name, record)
        _write_priors(store, cfg, source, name, record, rank, world, progress)
    return name


def _write_priors(
    store: EpisodeStore,
    cfg: PriorsConfig,
    source: GazeSource,
    name: str,
    record: dict[str, Any],
    rank: int,
    world: int,
    progress: bool,
) -> None:
    """The work of `make_priors`, under the writer lock."""
    fingerprint = record["settings_fingerprint"]
    sweep_stale_temps(store.prior_dir(name))
    old = store.prior_record(name)
    if rank == 0 and (cfg.overwrite or old is None or _settings_differ(old, record)):
        (store.prior_dir(name) / PRIOR_MANIFEST).unlink(missing_ok=True)
        store.write_prior_pending(name, record)
    indices = store.indices()
    todo = [i for i in indices if i % world == rank and (cfg.overwrite or not store.has_prior(name, i))]
    for i in indices:  # the files kept must have been made from this store's episodes, with these settings
        if i % world == rank and i not in todo:
            store.check_prior(name, i, fingerprint)
    skipped = len(indices) // max(world, 1) - len(todo)
    if skipped > 0:
        log.info("priors %s: %d episodes already done, skipping them", name, skipped)
    label = f"priors {name} in {store.root}"
    with Progress(label, len(todo), "episodes", enabled=progress) as bar:
        for i in todo:
            ep = store.read(i, cameras=[cfg.camera])
            heat, valid = source(ep, cfg.camera, tuple(cfg.size))
            agg, ok = aggregate(heat, valid, cfg.aggregation)
            store.write_prior(name, i, agg.numpy(), ok.numpy(), settings=fingerprint)
            bar.update()
    if all(store.has_prior(name, i) for i in indices):
        store.write_prior_info(name, manifest(store, name, record, indices))


def manifest(store: EpisodeStore, name: str, record: dict[str, Any], indices: list[int]) -> dict[str, Any]:
    """The manifest to write once every episode has its file: `record` when every file records its settings
    fingerprint; without the fingerprint when files made before it was recorded remain (read unchecked, with
    a warning); a `UsageError` when a file records another run's settings."""
    made_with = {i: store.prior_settings(name, i) for i in indices}
    other = [i for i, f in made_with.items() if f is not None and f != record["settings_fingerprint"]]
    if other:
        raise UsageError(
            f"priors {name!r} in {store.root}: the files of episode(s) {other[:5]} were made with other settings "
            f"than this run's (another `gazereg priors` run wrote them); recompute with --overwrite"
        )
    legacy = [i for i, f in made_with.items() if f is None]
    if not legacy:
        return record
    log.warning(
        "priors %s: %d file(s) predate settings fingerprints, so nothing checks that every file was made with "
        "one setting; recompute them (--overwrite) to record it",
        name,
        len(legacy),
    )
    return {k: v for k, v in record.items() if k != "settings_fingerprint"}


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    command = parse(
        {"default": PriorsCommand},
        sys.argv[1:] if argv is None else argv,
        prog="gazereg priors",
        description=__doc__ or "",
    )
    cfg = command.config()  # bad source names and parameters are UsageErrors (the gazereg CLI reports them)
    # `accelerate launch` / torchrun set these; each process takes every world-th episode (no sync needed).
    rank, world = int(os.environ.get("RANK", 0)), int(os.environ.get("WORLD_SIZE", 1))
    name = make_priors(cfg, rank=rank, world=world, progress=rank == 0)
    if rank == 0:
        print(f"priors {name!r} written to {Path(cfg.store) / 'priors' / name}")
    return 0


if (
    __name__ == "__main__"
):  # `accelerate launch -m gazereg.gaze.priors`: errors end as one line, as in `gazereg`
    _argv, _verbose = split_verbose(sys.argv[1:])
    raise SystemExit(report_errors("gazereg priors", main, _argv, _verbose))
