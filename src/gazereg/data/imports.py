"""Importing demonstrations from other formats into an episode store: the machinery every importer shares.

An importer (gazereg.data.formats.lerobot_v3, gazereg.data.formats.hdf5) lists its episodes as
`SourceEpisode`s, and `write_episodes` streams them into the store one at a time and resumes: the store
index of an episode is fixed by its source (LeRobot episode_index; HDF5 demo number), episodes already in
the store are skipped after checking that they came from the same source with the same settings, and every
episode is written atomically, so an error or a kill mid-episode leaves no partial episode behind.
`rotated_cameras` reads the importers' `rotate180` option, `recorded_gaze` a recorded gaze column.
"""

from __future__ import annotations

import logging
import shutil
import sys
import time
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from gazereg.data.errors import DataImportError, ImportUsageError
from gazereg.data.store import Episode, EpisodeStore, describe_non_finite
from gazereg.runtime.io import sweep_stale_temps

log = logging.getLogger(__name__)


@dataclass
class SourceEpisode:
    """One episode to import: its store index, who it is (compared on resume), and how to load it."""

    index: int
    identity: dict[str, Any]  # JSON-able; stored as meta["source"]
    load: Callable[[], Episode]
    length: int | None = None  # frames, if known without loading (for the progress bar)


def rotated_cameras(
    spec: str, cameras: list[str], auto: list[str] | None = None, where: str = ""
) -> list[str]:
    """Cameras to turn by 180 degrees from a `rotate180` option: none | all | auto | comma-separated names.

    `auto` means the importer's own default (`auto`; none where the importer has no default)."""
    spec = spec.strip()
    if spec == "auto":
        return list(auto or [])
    if spec in ("none", ""):
        return []
    if spec == "all":
        return list(cameras)
    names = [c.strip() for c in spec.split(",") if c.strip()]
    unknown = [c for c in names if c not in cameras]
    if unknown:
        raise ImportUsageError(
            f"rotate180 names camera(s) {unknown} that are not imported{where} ({cameras})"
        )
    return names


def recorded_gaze(points: np.ndarray, what: str, rotate180: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """A recorded gaze column as (T, 2) float32 (u, v) points (NaN where not finite) and their (T,) validity.

    `what` names the column in the error raised when it does not hold 2 values per frame; rotate180 turns the
    points with their camera (u -> 1-u, v -> 1-v)."""
    uv = points.astype(np.float32).reshape(len(points), -1)
    if uv.shape[1] != 2:
        raise DataImportError(f"{what} has {uv.shape[1]} values per frame, expected 2 (u, v)")
    valid = np.isfinite(uv).all(axis=1)
    uv[~valid] = np.nan
    if rotate180:
        uv = 1.0 - uv
    return uv, valid


def check_finite(arr: np.ndarray, what: str, name: str, keep: Collection[str] = ()) -> np.ndarray:
    """`arr` as it is when its values are finite or `name` is in `keep` (the importer's `nonfinite_ok`
    option); else a DataImportError naming `what`, the number of NaN/inf values and the first one's row."""
    problem = None if name in keep else describe_non_finite(arr)
    if problem is not None:
        raise DataImportError(
            f"{what} has {problem} (corrupt data?); pass --nonfinite-ok {name} to import it as it is"
        )
    return arr


def _same_source(stored: dict[str, Any], identity: dict[str, Any]) -> bool:
    return all(stored.get(k) == v for k, v in identity.items() if k not in ("path", "root"))


def write_episodes(
    store: EpisodeStore,
    episodes: Iterable[SourceEpisode],
    total: int | None = None,
    desc: str = "import",
    progress: bool = True,
) -> dict[str, Any]:
    """Load and write each episode not yet in the store; returns counts and throughput.

    An episode already in the store is skipped when its recorded meta["source"] matches the identity (same
    source format, episode, data set fingerprint and import settings; the path may differ), and refused
    otherwise, so a resumed import never mixes two data sets or two settings in one store. Temporaries that
    killed imports left in the store are removed first."""
    sweep_stale_temps(store.root)
    imported = skipped = frames = 0
    t0 = time.perf_counter()
    bar = tqdm(total=total, desc=desc, unit="ep", disable=not progress, file=sys.stderr)
    try:
        for item in episodes:
            if item.index in store:
                stored = store.meta(item.index).get("source", {})
                if not _same_source(stored, item.identity):
                    raise DataImportError(
                        f"store {store.root} already holds episode {item.index} from another source or with other "
                        f"import settings:\n  stored:    {stored}\n  importing: {item.identity}\n"
                        "import into a fresh store (or delete that episode folder to re-import it)"
                    )
                skipped += 1
            else:
                ep = item.load()
                ep.meta["source"] = dict(item.identity)
                try:
                    store.write(ep, item.index)
                except ValueError as e:
                    raise DataImportError(
                        f"{item.identity.get('path') or item.identity.get('root', '?')}: episode {item.identity.get('episode')}: {e}"
                    ) from e
                imported += 1
                frames += ep.length
            bar.update(1)
            elapsed = time.perf_counter() - t0
            bar.set_postfix(
                frames=frames, fps=f"{frames / max(elapsed, 1e-9):.0f}", skipped=skipped, refresh=False
            )
    finally:
        bar.close()
    seconds = time.perf_counter() - t0
    return {
        "imported": imported,
        "skipped": skipped,
        "frames": frames,
        "seconds": seconds,
        "frames_per_s": frames / max(seconds, 1e-9),
    }


def import_into(
    out: str | Path,
    episodes: Iterable[SourceEpisode],
    total: int | None = None,
    desc: str = "import",
    progress: bool = True,
) -> dict[str, Any]:
    """`write_episodes` into the store at `out`, creating it when it is not one yet. When the import fails
    (an error or an interrupt) before writing any episode into a store it created, what it created is removed
    (`out` itself when it did not exist); episodes already written stay, with a warning saying so, and the
    rerun resumes after them."""
    out = Path(out)
    existed, fresh = out.exists(), not (out / "store.json").exists()
    store = EpisodeStore(out, create=True)
    try:
        return write_episodes(store, episodes, total=total, desc=desc, progress=progress)
    except BaseException:
        kept = store.indices() if fresh else []
        if fresh and not kept:
            if existed:
                (out / "store.json").unlink(missing_ok=True)
                shutil.rmtree(out / "episodes", ignore_errors=True)
            else:
                shutil.rmtree(out, ignore_errors=True)
        elif kept:
            log.warning(
                "the %d episode(s) imported before the error are kept in %s; rerun the import to resume after "
                "them (or delete %s to start again)",
                len(kept),
                out,
                out,
            )
        raise
