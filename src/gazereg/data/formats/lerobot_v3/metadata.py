"""LeRobot v3.0 metadata and parquet files: meta/info.json, the episode and task tables, the per-frame data.

    <root>/meta/info.json                          features, fps, data_path / video_path templates
    <root>/meta/episodes/chunk-*/file-*.parquet    one row per episode (length, tasks, file indices, segments)
    <root>/meta/tasks.parquet                      task_index -> task string
    <root>/data/chunk-*/file-*.parquet             one row per frame (several episodes per file)

Every problem is raised as a `DataImportError` that names the file (and the episode where there is one).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gazereg.data.errors import DataImportError, ImportUsageError

log = logging.getLogger(__name__)

STANDARD_COLUMNS = ("timestamp", "frame_index", "episode_index", "index", "task_index")
"""Per-frame columns every LeRobot v3 data file has."""

DEFAULT_VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"


def require_pyarrow() -> tuple[Any, Any]:
    """The pyarrow and pyarrow.parquet modules, or an ImportError that says how to install them."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError as e:  # pragma: no cover - the `data` extra declares it
        raise ImportError(
            "LeRobot import/export needs pyarrow: pip install 'gazereg[data]' (or pip install pyarrow)"
        ) from e
    return pa, pq


def camera_name(key: str) -> str:
    """Store camera name of a LeRobot image feature key: `observation.images.front` -> `front`."""
    for prefix in ("observation.images.", "observation.image.", "observation."):
        if key.startswith(prefix) and len(key) > len(prefix):
            key = key[len(prefix) :]
            break
    return key.replace("/", "_")


def image_hw(ft: dict[str, Any]) -> tuple[int, int] | None:
    """(H, W) of an image feature from its shape and names ((H, W, C) by default, or (C, H, W))."""
    shape, names = list(ft.get("shape") or []), list(ft.get("names") or [])
    if len(shape) != 3:
        return None
    if names[:1] == ["channels"] or (not names and shape[0] == 3 and shape[-1] != 3):
        return int(shape[1]), int(shape[2])
    return int(shape[0]), int(shape[1])


def _is_rgb(ft: dict[str, Any]) -> bool:
    shape = ft.get("shape", [])
    is_depth = (ft.get("info") or {}).get("is_depth_map")
    return not is_depth and not (len(shape) == 3 and 3 not in (shape[0], shape[-1]))


def rgb_cameras(features: dict[str, dict[str, Any]]) -> dict[str, str]:
    """Store camera name -> feature key of every RGB image or video feature (depth maps are skipped)."""
    cameras = {}
    for key, ft in features.items():
        if ft.get("dtype") not in ("video", "image"):
            continue
        if not _is_rgb(ft):
            log.info("skipping %s: not an RGB camera", key)
            continue
        cameras[camera_name(key)] = key
    return cameras


# ----- parquet -----------------------------------------------------------------------------------------
def _unreadable(what: str, path: Path, e: Exception) -> DataImportError:
    return DataImportError(f"{what}: {path} could not be read (corrupt or truncated parquet?): {e}")


def parquet_columns(path: Path, what: str) -> list[str]:
    """The column names of a parquet file (from its schema, without reading the data)."""
    _, pq = require_pyarrow()
    if not path.exists():
        raise DataImportError(f"{what}: {path} does not exist")
    try:
        return list(pq.read_schema(path).names)
    except Exception as e:  # ArrowInvalid, OSError, thrift errors on corrupt files
        raise _unreadable(what, path, e) from e


def read_parquet(path: Path, what: str, columns: list[str] | None = None) -> Any:
    """A parquet file as a pyarrow Table; `what` names it in errors."""
    _, pq = require_pyarrow()
    if not path.exists():
        raise DataImportError(f"{what}: {path} does not exist")
    try:
        return pq.read_table(path, columns=columns)
    except Exception as e:  # ArrowInvalid, OSError, thrift errors on corrupt files
        raise _unreadable(what, path, e) from e


def to_numpy(col: Any, what: str) -> np.ndarray:
    """A parquet column of scalars or (fixed-size) lists of numbers as an (N,) or (N, d) array."""
    pa, _ = require_pyarrow()
    col = col.combine_chunks() if hasattr(col, "combine_chunks") else col
    t = col.type
    try:
        if pa.types.is_fixed_size_list(t):
            if col.null_count:
                raise DataImportError(f"{what} has null rows")
            return np.asarray(col.flatten().to_numpy(zero_copy_only=False)).reshape(len(col), t.list_size)
        if pa.types.is_list(t) or pa.types.is_large_list(t):
            rows = col.to_pylist()
            if any(r is None for r in rows) or len({len(r) for r in rows}) > 1:
                raise DataImportError(f"{what}: rows are null or of different lengths")
            return np.asarray(rows, dtype=np.float64 if pa.types.is_floating(t.value_type) else None)
        if pa.types.is_integer(t) or pa.types.is_floating(t) or pa.types.is_boolean(t):
            return col.to_numpy(zero_copy_only=False)
    except (pa.ArrowInvalid, ValueError) as e:
        if isinstance(e, DataImportError):
            raise
        raise DataImportError(f"{what} could not be converted: {e}") from e
    raise DataImportError(f"{what} has unsupported type {t}")


# ----- meta/ -------------------------------------------------------------------------------------------
@dataclass
class EpisodeMeta:
    """One row of meta/episodes: the episode's index, length, task strings and the whole row."""

    index: int
    length: int
    tasks: list[str]
    row: dict[str, Any]


def read_info(root: Path) -> dict[str, Any]:
    """meta/info.json of a LeRobot v3.x data set, checked for the version and the keys the reader needs."""
    info_path = root / "meta" / "info.json"
    if not info_path.exists():
        raise ImportUsageError(f"{root} is not a LeRobot data set: {info_path} does not exist")
    try:
        info = json.loads(info_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DataImportError(f"{info_path} is not valid JSON: {e}") from e
    version = str(info.get("codebase_version", "?"))
    if not version.startswith("v3"):
        raise DataImportError(
            f"{info_path}: codebase_version {version}; only LeRobot v3.x data sets are supported (convert v2.x with lerobot's converter)"
        )
    for k in ("features", "fps", "data_path"):
        if k not in info:
            raise DataImportError(f"{info_path} has no {k!r}")
    return info


def read_tasks(root: Path) -> dict[int, str]:
    """meta/tasks.parquet as task_index -> task string ({} where the file is absent)."""
    path = root / "meta" / "tasks.parquet"
    if not path.exists():
        return {}
    t = read_parquet(path, "task table")
    if "task_index" not in t.column_names or "task" not in t.column_names:
        raise DataImportError(f"{path} must have columns task_index and task, has {t.column_names}")
    return {int(i): str(s) for i, s in zip(t.column("task_index").to_pylist(), t.column("task").to_pylist())}


def _episode_meta(row: dict[str, Any], path: Path) -> EpisodeMeta:
    for k in ("episode_index", "length"):
        if row.get(k) is None:
            raise DataImportError(f"episode metadata {path}: a row has no {k!r}: {row}")
    tasks = [str(t) for t in (row.get("tasks") or [])]
    return EpisodeMeta(int(row["episode_index"]), int(row["length"]), tasks, row)


def read_episodes(root: Path) -> dict[int, EpisodeMeta]:
    """Every episode's metadata row (without the per-episode stats), by episode_index."""
    files = sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
    if not files:
        raise DataImportError(f"{root}: no episode metadata (meta/episodes/chunk-*/file-*.parquet)")
    out: dict[int, EpisodeMeta] = {}
    for path in files:
        what = "episode metadata"
        cols = [c for c in parquet_columns(path, what) if not c.startswith("stats/")]
        for row in read_parquet(path, what, cols).to_pylist():
            ep = _episode_meta(row, path)
            out[ep.index] = ep
    return dict(sorted(out.items()))


def data_file(root: Path, info: dict[str, Any], ep: EpisodeMeta) -> Path:
    """The data parquet file that holds an episode's frames."""
    try:
        rel = info["data_path"].format(
            chunk_index=int(ep.row["data/chunk_index"]), file_index=int(ep.row["data/file_index"])
        )
    except (KeyError, TypeError) as e:
        raise DataImportError(
            f"episode metadata of episode {ep.index} has no data/chunk_index or data/file_index"
        ) from e
    return root / rel


# ----- data/ -------------------------------------------------------------------------------------------
class DataFileCache:
    """The data file read last, with its rows indexed by episode, so consecutive episodes of one file read it
    once. `skip` leaves columns out (the image columns of cameras not imported)."""

    def __init__(self) -> None:
        self._key: tuple[Path, frozenset[str]] | None = None
        self._table: Any = None
        self._rows: dict[int, np.ndarray] = {}

    def episode_rows(self, path: Path, episode: int, skip: frozenset[str] = frozenset()) -> Any | None:
        """The episode's rows of the data file (a pyarrow Table, in file order), None if it has none."""
        if self._key != (path, skip):
            self._load(path, episode, skip)
        rows = self._rows.get(episode)
        return None if rows is None else self._table.take(rows)

    def _load(self, path: Path, episode: int, skip: frozenset[str]) -> None:
        self.close()
        what = f"episode {episode} data"
        columns = [c for c in parquet_columns(path, what) if c not in skip] if skip else None
        table = read_parquet(path, what, columns)
        if "episode_index" not in table.column_names:
            raise DataImportError(f"{what}: {path} has no episode_index column")
        ep_col = table.column("episode_index").to_numpy()
        order = np.argsort(ep_col, kind="stable")
        uniq, starts = np.unique(ep_col[order], return_index=True)
        ends = [*starts[1:], len(order)]
        self._rows = {int(u): order[s:e] for u, s, e in zip(uniq, starts, ends)}
        self._table, self._key = table, (path, skip)

    def close(self) -> None:
        self._table = self._key = None
        self._rows = {}
