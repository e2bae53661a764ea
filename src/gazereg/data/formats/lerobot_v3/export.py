"""Gaze priors out to LeRobot: a store's priors as a sidecar next to a LeRobot v3.0 data set (pyarrow only).

Export (`gazereg import export-priors --store STORE --prior NAME --out DIR`): `export_priors_lerobot` writes
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

from gazereg.data.importers import DataImportError, require_pyarrow
from gazereg.data.store import EpisodeStore
from gazereg.runtime.io import atomic_path, atomic_write_json

SIDECAR_FORMAT = "gazereg-priors-lerobot"
SIDECAR_VERSION = 1


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
    camera = info.get("camera")
    todo = [
        i
        for i in store.indices()
        if store.has_prior(prior_name, i) and (episode_map is None or i in episode_map)
    ]
    if not todo:
        raise DataImportError(
            f"store {store.root} has no {prior_name!r} priors to export"
            + (" for the given episode map" if episode_map else "")
        )
    plan: list[tuple[int, int]] = []  # (episode_index, store index)
    for i in todo:
        src = store.meta(i).get("source", {})
        e = (
            episode_map[i]
            if episode_map is not None
            else int(src["episode_index"])
            if src.get("format") == "lerobot_v3"
            else i
        )
        plan.append((e, i))
    plan.sort()
    dup = [e for (e, _), (e2, _) in zip(plan, plan[1:]) if e == e2]
    if dup:
        raise DataImportError(
            f"several store episodes map to episode_index {dup[0]}; pass an episode map that is one-to-one"
        )
    out_dir = Path(out_path)
    parquet_path, json_path = out_dir / "priors.parquet", out_dir / "priors.json"
    shape: tuple[int, int] | None = None
    n_frames, running, episodes = 0, 0, []
    writer = None
    from tqdm import tqdm

    with atomic_path(parquet_path) as tmp:
        try:
            for e, i in tqdm(
                plan, desc=f"export {prior_name}", unit="ep", disable=not progress, file=sys.stderr
            ):
                heat, valid = store.read_prior(prior_name, i)
                T, h, w = heat.shape
                if shape is None:
                    shape = (h, w)
                elif shape != (h, w):
                    raise DataImportError(
                        f"priors {prior_name!r}: episode {i} has {h}x{w} maps, others {shape[0]}x{shape[1]}"
                    )
                ep = store.read(i, cameras=[])
                undo = (
                    ep.meta.get("source", {}).get("format") == "lerobot_v3"
                    and ep.meta.get("orientation_applied", {}).get(camera) == "rot180"
                )
                if undo:
                    heat = heat[:, ::-1, ::-1]
                frame_index = (
                    np.asarray(ep.extras["lerobot.frame_index"], np.int64)
                    if "lerobot.frame_index" in ep.extras
                    else np.arange(T, dtype=np.int64)
                )
                index = (
                    np.asarray(ep.extras["lerobot.index"], np.int64)
                    if "lerobot.index" in ep.extras
                    else np.arange(running, running + T, dtype=np.int64)
                )
                running = int(index.max()) + 1
                flat = pa.FixedSizeListArray.from_arrays(
                    pa.array(np.ascontiguousarray(heat, np.float32).reshape(-1)), h * w
                )
                batch = pa.table(
                    {
                        "episode_index": pa.array(np.full(T, e, np.int64)),
                        "frame_index": pa.array(frame_index),
                        "index": pa.array(index),
                        "prior": flat,
                        "valid": pa.array(np.asarray(valid, bool)),
                    }
                )
                if writer is None:
                    writer = pq.ParquetWriter(tmp, batch.schema, compression="zstd")
                writer.write_table(batch)
                n_frames += T
                episodes.append({"episode_index": e, "store_index": i, "length": T, "rotation_undone": undo})
        finally:
            if writer is not None:
                writer.close()
    assert shape is not None
    atomic_write_json(
        json_path,
        {
            "format": SIDECAR_FORMAT,
            "version": SIDECAR_VERSION,
            "prior_name": prior_name,
            "prior_info": info,
            "camera": camera,
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
            "num_frames": n_frames,
            "num_episodes": len(episodes),
            "episodes": episodes,
            "store": str(store.root),
        },
    )
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
        raise DataImportError(f"{info_path}: not a {SIDECAR_FORMAT} file (format={info.get('format')!r})")
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


def export_main(argv: list[str]) -> int:
    from gazereg.runtime.config import parse

    cfg = parse(
        {"default": ExportPriorsConfig},
        argv,
        prog="gazereg import export-priors",
        description="Export a store's gaze priors as a LeRobot sidecar (priors.parquet + priors.json).",
    )
    mapping = None
    if cfg.episode_map:
        try:
            mapping = {int(a): int(b) for a, b in (p.split("=", 1) for p in cfg.episode_map)}
        except ValueError as e:
            raise DataImportError(
                f"--episode-map entries must be store_index=episode_index, got {cfg.episode_map}"
            ) from e
    path = export_priors_lerobot(cfg.store, cfg.prior, cfg.out, mapping, progress=True)
    print(json.dumps({"parquet": str(path), "info": str(path.with_suffix(".json"))}))
    return 0
