"""The gaze column of a LeRobot v3 data set on disk: read file by file from its parquet files, and checked for at
least one usable frame before a gaze policy is built (`check_gaze_data`)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from .errors import GazeUsageError
from .gaze_common import check_gaze_features
from .gaze_targets import HEATMAP, POINT, frame_valid, gaze_kind, gaze_valid_key

WHY_UNUSABLE = {
    POINT: "every (u, v) is NaN or outside [0, 1]^2",
    HEATMAP: "every heatmap is non-finite or <= 0 everywhere",
}


def _column_array(column: Any, frame_shape: tuple[int, ...], dtype: type, fill: Any) -> np.ndarray:
    """(N, *frame_shape) array of a pyarrow (chunked) column of per-frame values; missing values are `fill`."""
    import pyarrow as pa

    arr = column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column
    n = len(arr)
    flat = arr
    while (
        pa.types.is_list(flat.type)
        or pa.types.is_large_list(flat.type)
        or pa.types.is_fixed_size_list(flat.type)
    ):
        flat = flat.flatten()
    if arr.null_count == 0 and len(flat) == n * math.prod(frame_shape):
        values = flat.fill_null(fill).to_numpy(zero_copy_only=False)
        return values.astype(dtype).reshape(n, *frame_shape)
    out = np.full((n, *frame_shape), fill, dtype=dtype)  # null frames, or nested lists of uneven length
    for i, row in enumerate(arr.to_pylist()):
        if row is not None:
            out[i] = np.asarray(row, dtype=dtype).reshape(frame_shape)
    return out


def iter_gaze_column(
    root: Path, key: str, frame_shape: tuple[int, ...], flag_key: str | None
) -> Iterator[tuple[Tensor, Tensor | None]]:
    """Per parquet file of the data set at `root`: (values (N, *frame_shape) float32, flag (N,) bool or None) of
    the column `key` and its flag column `flag_key` (None where absent)."""
    import pyarrow.parquet as pq

    for f in sorted((Path(root) / "data").glob("*/*.parquet")):
        names = pq.read_schema(f).names
        if key not in names:
            raise GazeUsageError(f"gaze_key={key}", f"the data set's file {f} has no such column")
        cols = [key] + ([flag_key] if flag_key in names else [])
        table = pq.read_table(f, columns=cols)
        values = torch.from_numpy(_column_array(table.column(key), frame_shape, np.float32, np.nan))
        flag = None
        if flag_key in names:
            flag = torch.from_numpy(_column_array(table.column(flag_key), (1,), np.bool_, False)).reshape(-1)
        yield values, flag


def check_gaze_data(cfg: Any, meta: Any) -> None:
    """Raise GazeUsageError when the gaze column `cfg.gaze_key` of the data set described by `meta` (lerobot's
    LeRobotDatasetMetadata: .features, .root) has no usable frame in any episode (gaze_targets.frame_valid AND
    its flag column), so the gaze term could never be active. Reads the data set's files in order and stops at
    the first one with a usable frame. Checks nothing when gaze_weight is 0 or there is no data set (meta None,
    as in evaluation)."""
    if cfg.gaze_weight == 0 or meta is None:
        return
    features = meta.features
    check_gaze_features(cfg, features)
    key = cfg.gaze_key
    shape = tuple(int(d) for d in features[key]["shape"])
    kind = gaze_kind(key, shape)
    flag_key = gaze_valid_key(key)
    flag_key = flag_key if flag_key in features else None
    root = getattr(meta, "root", None)
    if root is None:
        return
    frames = 0
    for values, flag in iter_gaze_column(Path(root), key, shape, flag_key):
        ok = frame_valid(values, kind)
        if flag is not None:
            ok &= flag
        if bool(ok.any()):
            return
        frames += len(values)
    why = WHY_UNUSABLE.get(kind, "every distribution is non-finite or has no positive mass")
    if flag_key is not None:
        why += f" (or flagged false in {flag_key})"
    raise GazeUsageError(
        f"gaze_key={key}",
        f"none of the {frames} frames of the data set at {root} has usable gaze: {why}, so the gaze term would "
        "never be active; fix the column or set --policy.gaze_weight=0",
    )
