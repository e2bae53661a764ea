"""A store's gaze priors into a NEW version of the LeRobot v3.0 data set it was imported from (pyarrow only).

`write_gaze_dataset` (`gazereg import write-gaze --store STORE --prior NAME --root DATASET --out NEW_ROOT`)
copies the data set to NEW_ROOT (videos hard-linked where the file system allows, else copied; built in a
temporary folder beside NEW_ROOT and renamed into place, so NEW_ROOT is either complete or absent; the source is
never modified) and adds two per-frame features of the prior's camera `<cam>`:

    gaze.<cam>.heatmap   float32 (h, w), names ["height", "width"]: the store's (aggregated) prior over the
                         data set's own frame (u right, v down; a 180-degree turn applied at import is undone),
                         each valid frame summing to 1, invalid frames all zero
    gaze.<cam>.valid     bool (1,): whether the frame has gaze

Both are written as `LeRobotDataset` writes such features (the heatmap as a `datasets.Array2D` column, the
flag as a bool `Value`, with the parquet files' huggingface schema metadata updated), declared in
meta/info.json `features`, and given statistics in meta/stats.json and per episode in meta/episodes
(`stats/<key>/<min|max|mean|std|count|q01|q10|q50|q90|q99>`, per element over frames, as lerobot's
`compute_episode_stats` lays them out), so `lerobot.datasets.LeRobotDataset` and every LeRobot tool see them.

Episodes are matched by what the LeRobot import recorded (meta["source"]: format, data set fingerprint,
episode_index, length; extras lerobot.index): a store not imported from this data set, or an episode whose
length or frame indices differ, is refused. Data set episodes the store holds no prior for get valid = false.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from gazereg.data.errors import ExportUsageError
from gazereg.data.formats.lerobot_v3.dataset import LeRobotV3Dataset
from gazereg.data.formats.lerobot_v3.metadata import read_parquet, require_pyarrow
from gazereg.data.store import EpisodeStore
from gazereg.runtime.io import atomic_dir, atomic_write_json

log = logging.getLogger(__name__)

QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
_HF_META = b"huggingface"


def gaze_feature_keys(camera: str) -> tuple[str, str]:
    """(heatmap key, validity key) of a camera: `("gaze.<camera>.heatmap", "gaze.<camera>.valid")`."""
    return f"gaze.{camera}.heatmap", f"gaze.{camera}.valid"


@dataclass(frozen=True)
class GazeMaps:
    """One data set episode's gaze: heat (T, h, w) float32 in frame_index order, valid (T,) bool."""

    heat: np.ndarray
    valid: np.ndarray


# ----- matching the store to the data set ------------------------------------------------------------------
def _match_episodes(store: EpisodeStore, prior: str, dataset: LeRobotV3Dataset) -> dict[int, int]:
    """{episode_index: store index} of every store episode holding `prior`; refuses (ExportUsageError) a store
    episode not imported from `dataset` or one whose length or global indices differ from the data set's."""
    out: dict[int, int] = {}
    fp = dataset.fingerprint()
    for i in store.indices():
        if not store.has_prior(prior, i):
            continue
        meta = store.meta(i)
        src = meta.get("source", {})
        if src.get("format") != "lerobot_v3" or src.get("dataset") != fp:
            raise ExportUsageError(
                f"store {store.root} episode {i} was not imported from the LeRobot data set {dataset.root} "
                f"(source {src.get('root', src.get('format', '?'))}, schema {src.get('dataset')} vs {fp})"
            )
        e = int(src["episode_index"])
        ep = dataset.episodes.get(e)
        if ep is None or ep.length != int(meta["length"]):
            have = "no such episode" if ep is None else f"length {ep.length}"
            raise ExportUsageError(
                f"store {store.root} episode {i} (episode_index {e}, length {meta['length']}) does not match "
                f"{dataset.root}: {have}"
            )
        if e in out:
            raise ExportUsageError(
                f"store {store.root} episodes {out[e]} and {i} both come from episode_index {e}"
            )
        out[e] = i
    if not out:
        raise ExportUsageError(f"store {store.root} has no {prior!r} priors to write")
    return out


def resize_maps(heat: np.ndarray, valid: np.ndarray, size: tuple[int, int] | None) -> np.ndarray:
    """heat (T, h, w) -> (T, *size) float32 (area-averaged when shrinking, bilinear otherwise), valid frames
    renormalised to sum 1 and invalid ones zero; unchanged in shape when `size` is None or equal."""
    if size is not None and tuple(heat.shape[1:]) != tuple(size):
        x = torch.from_numpy(np.ascontiguousarray(heat, np.float32))[:, None]
        shrink = size[0] <= heat.shape[1] and size[1] <= heat.shape[2]
        kw: dict[str, Any] = {} if shrink else {"align_corners": False}
        x = F.interpolate(x, size=tuple(size), mode="area" if shrink else "bilinear", **kw)[:, 0]
        heat = x.clamp_min(0).numpy()
    total = heat.sum(axis=(1, 2), keepdims=True)
    ok = valid[:, None, None] & (total > 0)
    return np.where(ok, heat / np.maximum(total, 1e-30), 0.0).astype(np.float32)


def _store_maps(
    store: EpisodeStore, prior: str, i: int, camera: str, size: tuple[int, int] | None
) -> GazeMaps:
    """Store episode i's prior in the data set's frame (a turn applied at import undone), resized to `size`."""
    heat, valid = store.read_prior(prior, i)
    if store.meta(i).get("orientation_applied", {}).get(camera) == "rot180":
        heat = heat[:, ::-1, ::-1]
    return GazeMaps(resize_maps(heat, valid, size), valid.astype(bool))


def _check_indices(store: EpisodeStore, i: int, e: int, index: np.ndarray) -> None:
    """Refuse a store episode whose recorded global indices differ from the data set rows' (frame order)."""
    ep = store.read(i, cameras=[])
    recorded = ep.extras.get("lerobot.index")
    if recorded is not None and not np.array_equal(np.asarray(recorded, np.int64), index):
        raise ExportUsageError(
            f"store {store.root} episode {i}: its recorded frame indices differ from episode_index {e} of the "
            "data set (a different data set with the same schema?)"
        )


# ----- parquet columns -------------------------------------------------------------------------------------
def _array2d(pa: Any, heat: np.ndarray) -> Any:
    """(N, h, w) float32 -> list<list<float32>> Array (the storage of `datasets.Array2D`)."""
    N, h, w = heat.shape
    inner = pa.ListArray.from_arrays(
        pa.array(np.arange(0, N * h * w + 1, w, dtype=np.int32)),
        pa.array(np.ascontiguousarray(heat, np.float32).reshape(-1)),
    )
    return pa.ListArray.from_arrays(pa.array(np.arange(0, N * h + 1, h, dtype=np.int32)), inner)


def _hf_features(schema: Any, keys: tuple[str, str], shape: tuple[int, int]) -> dict[bytes, bytes]:
    """The schema metadata with the huggingface `datasets` features of the two gaze columns added."""
    meta = dict(schema.metadata or {})
    hf = json.loads(meta.get(_HF_META, b"{}") or b"{}")
    feats = hf.setdefault("info", {}).setdefault("features", {})
    feats[keys[0]] = {"shape": list(shape), "dtype": "float32", "_type": "Array2D"}
    feats[keys[1]] = {"dtype": "bool", "_type": "Value"}
    meta[_HF_META] = json.dumps(hf).encode()
    return meta


def _with_gaze(table: Any, maps: dict[int, GazeMaps], keys: tuple[str, str], shape: tuple[int, int]) -> Any:
    """A data file's table with the two gaze columns (replacing any of the same name), rows in file order."""
    pa, _ = require_pyarrow()
    ep_col = table.column("episode_index").to_numpy()
    fr_col = table.column("frame_index").to_numpy()
    heat = np.zeros((table.num_rows, *shape), np.float32)
    valid = np.zeros(table.num_rows, bool)
    for e in np.unique(ep_col):
        m = maps.get(int(e))
        if m is not None:
            rows = np.nonzero(ep_col == e)[0]
            heat[rows], valid[rows] = m.heat[fr_col[rows]], m.valid[fr_col[rows]]
    for k in keys:
        if k in table.column_names:
            table = table.drop_columns([k])
    ext = {b"ARROW:extension:name": b"datasets.features.features.Array2DExtensionType"}
    ext[b"ARROW:extension:metadata"] = json.dumps([list(shape), "float32"]).encode()
    heat_field = pa.field(keys[0], pa.list_(pa.list_(pa.float32())), metadata=ext)
    table = table.append_column(heat_field, _array2d(pa, heat))
    table = table.append_column(pa.field(keys[1], pa.bool_()), pa.array(valid))
    return table.replace_schema_metadata(_hf_features(table.schema, keys, shape))


# ----- statistics ------------------------------------------------------------------------------------------
def feature_stats(x: np.ndarray) -> dict[str, np.ndarray]:
    """Per-element statistics over frames of x (N, ...) as lerobot lays them out: min, max, mean, std,
    quantiles (each of shape x.shape[1:]) and count (1,)."""
    x = x.astype(np.float64)
    out = {"min": x.min(0), "max": x.max(0), "mean": x.mean(0), "std": x.std(0)}
    out["count"] = np.array([x.shape[0]], np.int64)
    for q in QUANTILES:
        out[f"q{round(q * 100):02d}"] = np.quantile(x, q, axis=0)
    return out


def _gaze_stats(heat: np.ndarray, valid: np.ndarray, keys: tuple[str, str]) -> dict[str, dict[str, list]]:
    """{heatmap key: stats of (N, h, w) maps, valid key: stats of the (N, 1) flag} as JSON-ready lists."""
    stats = {keys[0]: feature_stats(heat), keys[1]: feature_stats(valid.reshape(-1, 1).astype(np.float64))}
    return {k: {s: v.tolist() for s, v in st.items()} for k, st in stats.items()}


def _episode_stats_columns(
    episode_index: np.ndarray, maps: dict[int, GazeMaps], keys: tuple[str, str]
) -> dict[str, list]:
    """`stats/<key>/<stat>` columns of meta/episodes rows (one per episode_index, in row order)."""
    cols: dict[str, list] = {}
    for e in episode_index:
        m = maps[int(e)]
        for key, st in _gaze_stats(m.heat, m.valid, keys).items():
            for s, v in st.items():
                cols.setdefault(f"stats/{key}/{s}", []).append(v)
    return cols


def _rewrite_episode_meta(src: Path, dst: Path, maps: dict[int, GazeMaps], keys: tuple[str, str]) -> None:
    """Copy meta/episodes/*/*.parquet with the per-episode stats of the gaze features added."""
    pa, pq = require_pyarrow()
    for path in sorted((src / "meta" / "episodes").glob("chunk-*/file-*.parquet")):
        table = read_parquet(path, "episode metadata")
        cols = _episode_stats_columns(table.column("episode_index").to_numpy(), maps, keys)
        for name, values in cols.items():
            if name in table.column_names:
                table = table.drop_columns([name])
            table = table.append_column(name, pa.array(values))
        out = dst / path.relative_to(src)
        out.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(table, out, compression="snappy")


# ----- the new data set version ----------------------------------------------------------------------------
_REWRITTEN = {Path("meta/info.json"), Path("meta/stats.json")}
_REWRITTEN_DIRS = (Path("data"), Path("meta/episodes"))


def _link_or_copy(src: Path, dst: Path) -> None:
    """Hard-link a file (videos: never rewritten in place by LeRobot), copying where linking fails."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


def _copy_unchanged(root: Path, dst: Path) -> None:
    """Every file of the data set except those rewritten here; videos/ hard-linked, the rest copied (fresh
    permissions, so the new version is writable even when the source is read-only)."""
    for folder, _, files in os.walk(root):
        rel = Path(folder).relative_to(root)
        if any(rel == d or d in rel.parents for d in _REWRITTEN_DIRS):
            continue
        (dst / rel).mkdir(parents=True, exist_ok=True)
        for name in files:
            if rel / name in _REWRITTEN:
                continue
            link = rel.parts[:1] == ("videos",)
            (_link_or_copy if link else shutil.copyfile)(Path(folder) / name, dst / rel / name)


def _write_data_files(
    dataset: LeRobotV3Dataset,
    dst: Path,
    store: EpisodeStore,
    match: dict[int, int],
    maps: dict[int, GazeMaps],
    keys: tuple[str, str],
    shape: tuple[int, int],
) -> None:
    """Every data parquet file with the gaze columns added; checks each matched episode's global indices."""
    _, pq = require_pyarrow()
    for path in sorted((dataset.root / "data").glob("*/*.parquet")):
        table = read_parquet(path, "data file")
        ep_col, fr_col = table.column("episode_index").to_numpy(), table.column("frame_index").to_numpy()
        index = table.column("index").to_numpy() if "index" in table.column_names else None
        for e in np.unique(ep_col):
            rows = np.nonzero(ep_col == e)[0]
            if int(e) in match and index is not None:
                _check_indices(store, match[int(e)], int(e), index[rows[np.argsort(fr_col[rows])]])
        out = dst / path.relative_to(dataset.root)
        out.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(_with_gaze(table, maps, keys, shape), out, compression="snappy")


def _write_meta(
    dataset: LeRobotV3Dataset,
    dst: Path,
    maps: dict[int, GazeMaps],
    keys: tuple[str, str],
    shape: tuple[int, int],
) -> None:
    """meta/info.json (the two features declared), meta/stats.json and meta/episodes (their statistics)."""
    info = json.loads((dataset.root / "meta" / "info.json").read_text())
    info["features"][keys[0]] = {"dtype": "float32", "shape": list(shape), "names": ["height", "width"]}
    info["features"][keys[1]] = {"dtype": "bool", "shape": [1], "names": None}
    atomic_write_json(dst / "meta" / "info.json", info)
    stats_path = dataset.root / "meta" / "stats.json"
    stats = json.loads(stats_path.read_text()) if stats_path.exists() else {}
    order = sorted(maps)
    heat = np.concatenate([maps[e].heat for e in order])
    valid = np.concatenate([maps[e].valid for e in order])
    stats.update(_gaze_stats(heat, valid, keys))
    atomic_write_json(dst / "meta" / "stats.json", stats)
    _rewrite_episode_meta(dataset.root, dst, maps, keys)


def _check_paths(root: Path, out: Path) -> None:
    if not (root / "meta" / "info.json").exists():
        raise ExportUsageError(
            f"{root} is not a LeRobot data set: {root / 'meta' / 'info.json'} does not exist"
        )
    r, o = root.resolve(), out.resolve()
    if o == r or r in o.parents:
        raise ExportUsageError(f"--out {out} is inside the source data set {root}; choose a new folder")
    if out.exists():
        raise ExportUsageError(
            f"--out {out} already exists; choose a new folder (the source stays unchanged)"
        )


def write_gaze_dataset(
    store: EpisodeStore | str | Path,
    prior_name: str,
    root: str | Path,
    out: str | Path,
    size: tuple[int, int] | None = None,
    progress: bool = False,
) -> dict[str, Any]:
    """Write `out`: a new version of the LeRobot v3.0 data set at `root` with the store's prior `prior_name`
    as features gaze.<cam>.heatmap (float32 (h, w), resized to `size` if given) and gaze.<cam>.valid (bool)
    (see the module docstring). Returns a report: out, camera, keys, shape, episodes written, frames."""
    root, out = Path(root), Path(out)
    _check_paths(root, out)
    store = store if isinstance(store, EpisodeStore) else EpisodeStore(store)
    camera = store.prior_info(prior_name).get("camera")
    dataset = LeRobotV3Dataset(root)
    try:
        if camera not in dataset.cameras:
            raise ExportUsageError(
                f"priors {prior_name!r} are of camera {camera!r}; {root} has {sorted(dataset.cameras)}"
            )
        match = _match_episodes(store, prior_name, dataset)
        maps = {
            e: _store_maps(store, prior_name, i, camera, size)
            for e, i in tqdm(match.items(), desc=f"read {prior_name}", disable=not progress, file=sys.stderr)
        }
        shapes = {m.heat.shape[1:] for m in maps.values()}
        if len(shapes) > 1:
            raise ExportUsageError(
                f"priors {prior_name!r} have maps of several sizes {sorted(shapes)}; pass --size"
            )
        shape = (int(next(iter(shapes))[0]), int(next(iter(shapes))[1]))
        for e, ep in dataset.episodes.items():
            maps.setdefault(e, GazeMaps(np.zeros((ep.length, *shape), np.float32), np.zeros(ep.length, bool)))
        keys = gaze_feature_keys(camera)
        with atomic_dir(out) as tmp:
            _copy_unchanged(root, tmp)
            _write_data_files(dataset, tmp, store, match, maps, keys, shape)
            _write_meta(dataset, tmp, maps, keys, shape)
    finally:
        dataset.close()
    frames = int(sum(m.valid.sum() for m in maps.values()))
    log.info("wrote %s: %s + %s (%dx%d) for %d episodes", out, *keys, *shape, len(match))
    return {
        "out": str(out),
        "camera": camera,
        "heatmap_key": keys[0],
        "valid_key": keys[1],
        "shape": list(shape),
        "episodes": sorted(match),
        "valid_frames": frames,
    }
