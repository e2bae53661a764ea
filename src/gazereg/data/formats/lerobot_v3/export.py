"""Gaze priors out to LeRobot: a store's priors as a sidecar next to a LeRobot v3.0 data set (pyarrow only).

Export (`gazereg import export-priors --store STORE --prior NAME --out DIR`, gazereg.data.export):
`export_priors_lerobot` writes
DIR/priors.parquet (columns episode_index, frame_index, index int64; prior fixed_size_list<float32>[h*w],
row-major (h, w), each valid row summing to 1; valid bool) and DIR/priors.json (format, the prior's info, shape,
camera, frame convention, episodes). The suggested place is <lerobot root>/gaze_priors/<prior name>/, next to
the data set, where a LeRobot training plugin reads it with `read_priors_lerobot` (or pyarrow alone).

Rows are keyed by what the LeRobot import (gazereg.data.formats.lerobot_v3) recorded, and a 180-degree turn applied at
import is undone, so a sidecar for a LeRobot-imported episode is always in the data set's own frame.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from gazereg.data.errors import DataExportError, ExportUsageError
from gazereg.data.formats.lerobot_v3.metadata import require_pyarrow
from gazereg.data.store import EpisodeStore
from gazereg.runtime.io import atomic_path, atomic_write_json

SIDECAR_FORMAT = "gazereg-priors-lerobot"
SIDECAR_VERSION = 1


def _export_plan(
    store: EpisodeStore, prior_name: str, episode_map: dict[int, int] | None
) -> list[tuple[int, int]]:
    """`(episode_index, store index)` of every episode to export, sorted; refuses a map that is not one-to-one."""
    todo = [
        i
        for i in store.indices()
        if store.has_prior(prior_name, i) and (episode_map is None or i in episode_map)
    ]
    if not todo:
        raise ExportUsageError(
            f"store {store.root} has no {prior_name!r} priors to export"
            + (" for the given episode map" if episode_map else "")
        )
    plan: list[tuple[int, int]] = []
    for i in todo:
        src = store.meta(i).get("source", {})
        if episode_map is not None:
            plan.append((episode_map[i], i))
        elif src.get("format") == "lerobot_v3":
            plan.append((int(src["episode_index"]), i))
        else:
            plan.append((i, i))
    plan.sort()
    dup = [e for (e, _), (e2, _) in zip(plan, plan[1:]) if e == e2]
    if dup:
        raise DataExportError(
            f"several store episodes map to episode_index {dup[0]}; pass an episode map that is one-to-one"
        )
    return plan


@dataclass(frozen=True)
class _EpisodeRows:
    """One episode's rows of the sidecar."""

    table: Any
    """pyarrow Table: episode_index, frame_index, index, prior (h*w floats), valid"""
    shape: tuple[int, int]
    """`(h, w)` of its maps"""
    record: dict[str, Any]
    """its entry in priors.json's episode list"""
    next_index: int
    """the global `index` after its last frame"""


def _episode_rows(
    pa: Any, store: EpisodeStore, prior_name: str, camera: str | None, e: int, i: int, running: int
) -> _EpisodeRows:
    """The rows of store episode `i` as data set episode `e` (`running`: the next global index when the
    episode did not come from LeRobot); maps are turned back into the data set's frame where the import
    turned them."""
    heat, valid = store.read_prior(prior_name, i)
    T, h, w = heat.shape
    ep = store.read(i, cameras=[])
    undo = (
        ep.meta.get("source", {}).get("format") == "lerobot_v3"
        and ep.meta.get("orientation_applied", {}).get(camera) == "rot180"
    )
    if undo:
        heat = heat[:, ::-1, ::-1]
    frame_index = np.asarray(ep.extras.get("lerobot.frame_index", np.arange(T)), np.int64)
    default_index = np.arange(running, running + T, dtype=np.int64)
    index = np.asarray(ep.extras.get("lerobot.index", default_index), np.int64)
    flat = pa.FixedSizeListArray.from_arrays(
        pa.array(np.ascontiguousarray(heat, np.float32).reshape(-1)), h * w
    )
    table = pa.table(
        {
            "episode_index": pa.array(np.full(T, e, np.int64)),
            "frame_index": pa.array(frame_index),
            "index": pa.array(index),
            "prior": flat,
            "valid": pa.array(np.asarray(valid, bool)),
        }
    )
    record = {"episode_index": e, "store_index": i, "length": T, "rotation_undone": undo}
    return _EpisodeRows(table, (h, w), record, int(index.max()) + 1)


def _sidecar_info(
    store: EpisodeStore,
    prior_name: str,
    info: dict[str, Any],
    shape: tuple[int, int],
    episodes: list[dict[str, Any]],
) -> dict[str, Any]:
    """The content of priors.json."""
    return {
        "format": SIDECAR_FORMAT,
        "version": SIDECAR_VERSION,
        "prior_name": prior_name,
        "prior_info": info,
        "camera": info.get("camera"),
        "shape": list(shape),
        "dtype": "float32",
        "columns": {
            "episode_index": "int64",
            "frame_index": "int64",
            "index": "int64",
            "prior": f"fixed_size_list<float32>[{shape[0] * shape[1]}]",
            "valid": "bool",
        },
        "layout": "prior is a row-major (h, w) map flattened; rows with valid=true sum to 1; invalid rows are zero",
        "frame": "u right, v down; LeRobot-imported episodes in the data set's own frames (rotation_undone "
        "tells where a turn applied at import was undone), other episodes in the store's upright frames",
        "num_frames": sum(e["length"] for e in episodes),
        "num_episodes": len(episodes),
        "episodes": episodes,
        "store": str(store.root),
    }


def export_priors_lerobot(
    store: EpisodeStore | str | Path,
    prior_name: str,
    out_path: str | Path,
    episode_map: dict[int, int] | None = None,
    progress: bool = False,
) -> Path:
    """Write a store's priors as a LeRobot sidecar: out_path/priors.parquet + out_path/priors.json.

    Rows are keyed by (episode_index, frame_index) and the data set's global `index`, taken from what the
    LeRobot import recorded (meta["source"]["episode_index"], extras lerobot.frame_index / lerobot.index).
    episode_map {store index: episode_index} overrides that; when given, only mapped episodes are exported.
    Episodes not imported from LeRobot get episode_index = store index, frame_index = 0..T-1 and a running
    index. Frames: for LeRobot-imported episodes the heatmaps are put back into the data set's own frame (a
    180-degree turn applied at import is undone); other episodes (e.g. HDF5 imports, whose LIBERO frames were
    turned upright, as LeRobot's LIBERO conversions are) are exported in the store's upright frame.
    Returns the parquet path."""
    pa, pq = require_pyarrow()
    store = store if isinstance(store, EpisodeStore) else EpisodeStore(store)
    info = store.prior_info(prior_name)
    plan = _export_plan(store, prior_name, episode_map)
    out_dir = Path(out_path)
    parquet_path = out_dir / "priors.parquet"
    shape: tuple[int, int] | None = None
    running, episodes, writer = 0, [], None
    with atomic_path(parquet_path) as tmp:
        try:
            for e, i in tqdm(
                plan, desc=f"export {prior_name}", unit="ep", disable=not progress, file=sys.stderr
            ):
                rows = _episode_rows(pa, store, prior_name, info.get("camera"), e, i, running)
                if shape is not None and rows.shape != shape:
                    raise DataExportError(
                        f"priors {prior_name!r}: episode {i} has {rows.shape[0]}x{rows.shape[1]} maps, "
                        f"others {shape[0]}x{shape[1]}"
                    )
                shape = rows.shape
                if writer is None:
                    writer = pq.ParquetWriter(tmp, rows.table.schema, compression="zstd")
                writer.write_table(rows.table)
                running = rows.next_index
                episodes.append(rows.record)
        finally:
            if writer is not None:
                writer.close()
    assert shape is not None  # the plan is never empty
    atomic_write_json(out_dir / "priors.json", _sidecar_info(store, prior_name, info, shape, episodes))
    return parquet_path


@dataclass
class LeRobotPriors:
    """A priors sidecar in memory: N rows sorted by (episode_index, frame_index); priors (N, h, w) float32."""

    info: dict[str, Any]
    episode_index: np.ndarray
    frame_index: np.ndarray
    index: np.ndarray
    priors: np.ndarray
    valid: np.ndarray
    _rows: dict[tuple[int, int], int] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self._rows = {
            (int(e), int(f)): r for r, (e, f) in enumerate(zip(self.episode_index, self.frame_index))
        }

    def get(self, episode_index: int, frame_index: int) -> tuple[np.ndarray, bool]:
        """The (h, w) prior and its validity for one frame; KeyError if the sidecar lacks it."""
        r = self._rows[(int(episode_index), int(frame_index))]
        return self.priors[r], bool(self.valid[r])


def read_priors_lerobot(path: str | Path) -> LeRobotPriors:
    """Read a sidecar written by export_priors_lerobot (path: its folder or its priors.parquet)."""
    _, pq = require_pyarrow()
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    info_path, parquet_path = folder / "priors.json", folder / "priors.parquet"
    if not info_path.exists() or not parquet_path.exists():
        raise FileNotFoundError(f"{folder} is not a priors sidecar (needs priors.json and priors.parquet)")
    info = json.loads(info_path.read_text())
    if info.get("format") != SIDECAR_FORMAT:
        raise DataExportError(f"{info_path}: not a {SIDECAR_FORMAT} file (format={info.get('format')!r})")
    h, w = info["shape"]
    t = pq.read_table(parquet_path)
    prior = t.column("prior").combine_chunks()
    priors = np.asarray(prior.flatten().to_numpy(), np.float32).reshape(len(prior), h, w)
    return LeRobotPriors(
        info=info,
        episode_index=t.column("episode_index").to_numpy(),
        frame_index=t.column("frame_index").to_numpy(),
        index=t.column("index").to_numpy(),
        priors=priors,
        valid=t.column("valid").to_numpy(zero_copy_only=False).astype(bool),
    )
