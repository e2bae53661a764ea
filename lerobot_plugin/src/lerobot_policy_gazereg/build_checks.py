"""What a gaze policy checks when it is built, from its config and the data set's metadata, before its model is
built (so before any weights load): `--policy.gaze_layers` against the layers the model will have, the gaze
column's content (gaze_data.check_gaze_data) and, for a column holding a distribution over image tokens (n,) per
frame, n against the regularized camera's token grid (`check_token_grid`). Each refusal is one line naming the
option or column (errors.refusing; exit status 2 inside lerobot-train).

The model's layer count and token grid come from the same configs the model is built from (SmolVLA: the VLM's
config at `vlm_model_name`; pi0 / pi0.5: lerobot's gemma variant and PaliGemma vision config); the training
forward checks the built model's token count again (gaze_common.check_token_count)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from gazereg.patches import PatchGeometry

from .errors import GazeUsageError, refusing
from .gaze_common import check_gaze_layers
from .gaze_data import check_gaze_data
from .gaze_targets import TOKENS, gaze_kind


def gaze_frame_shape(config: Any, meta: Any) -> tuple[int, ...] | None:
    """The data set's shape per frame of the gaze column (LeRobotDatasetMetadata.features), or None without one."""
    feature = getattr(meta, "features", {}).get(config.gaze_key) if meta is not None else None
    return tuple(int(d) for d in feature["shape"]) if feature else None


def check_token_grid(cfg: Any, meta: Any, geometry: Callable[[], PatchGeometry]) -> None:
    """Raise GazeUsageError naming the gaze column when it holds a distribution over image tokens (n,) per frame
    (gaze_targets.TOKENS) and n is not the regularized camera's token count, `geometry()` (called only then).
    Checks nothing when gaze_weight is 0, without a data set (meta None) or for point and heatmap columns."""
    shape = gaze_frame_shape(cfg, meta)
    if cfg.gaze_weight == 0 or shape is None or gaze_kind(cfg.gaze_key, shape) != TOKENS:
        return
    geom = geometry()
    if shape[0] != geom.n_patches:
        h, w = geom.grid_hw
        raise GazeUsageError(
            f"gaze_key={cfg.gaze_key}",
            f"the column holds {shape[0]} values per frame, read as a distribution over image tokens, but "
            f"camera {cfg.gaze_camera_key()} has {geom.n_patches} image tokens ({h}x{w} grid); store one value "
            "per token, row-major",
        )


def check_before_build(
    cfg: Any,
    meta: Any,
    layers: tuple[Sequence[int], str],
    geometry: Callable[[], PatchGeometry],
) -> None:
    """The checks a gaze policy runs at the start of its __init__. `layers`: (the layer indices gaze_layers may
    name, what the model has, for the message); `geometry`: the regularized camera's token geometry (called only
    for a token-distribution column); `meta`: the data set's metadata, or None (evaluation: nothing to check but
    the layers)."""
    with refusing():
        check_gaze_layers(cfg.gaze_layers, *layers)
        check_gaze_data(cfg, meta)
        check_token_grid(cfg, meta, geometry)
