"""Gaze columns of a LeRobot data set -> gaze distributions over SmolVLA's image tokens of one camera.

A column may hold, per frame:
- a gaze point (u, v) in [0, 1] (u right, v down, in the stored frame): a Gaussian heatmap around it
  (sigma a fraction of the frame height), NaN or out-of-frame -> no gaze (invalid frame);
- a heatmap (h, w) over the stored frame, at any resolution: pooled onto the token grid (what
  `gazereg import write-gaze` writes as `gaze.<camera>.heatmap`, with its flag `gaze.<camera>.valid`);
- a distribution over the camera's tokens (n_tokens,) already on the token grid: used as it is.
A validity column next to it (`gaze_valid_key`: `gaze.<camera>.valid` for `gaze.<camera>.heatmap`) masks frames
further: a frame counts only where the column is valid AND the flag is true. Any other shape per frame is
refused with the column's name (`gaze_kind`); LeRobot loads gaze.* columns one frame per sample, so a shape such as
(2, 8, 8) is never guessed to be a history of two maps.

The stored frame reaches SmolVLA through `resize_with_pad` (keep the aspect ratio, pad on the LEFT and TOP,
content at the bottom-right) to `resize_imgs_with_padding` (width, height), then SigLIP patches and the
connector's pixel shuffle. gazereg's PatchGeometry places fitted content at the top-left ('topleft') or the
centre, so the bottom-right placement is expressed exactly as: rotate the frame by 180 degrees, place it top-left,
pool, and rotate the token grid back (reverse the row-major vector).
"""

from __future__ import annotations

import torch
from torch import Tensor

from gazereg.heatmaps import heatmaps_from_points
from gazereg.patches import PatchGeometry, patch_distribution

from .errors import GazeUsageError


def smolvla_geometry(
    src_hw: tuple[int, int], input_wh: tuple[int, int] | None, patch_size: int, pixel_shuffle: int
) -> tuple[PatchGeometry, bool]:
    """(geometry, flip): the PatchGeometry to pool with and whether the pooled vector must be reversed.

    src_hw: stored frame (height, width); input_wh: SmolVLA's `resize_imgs_with_padding` (width, height) or None
    (frames used at their own size)."""
    if input_wh is None:
        return PatchGeometry(
            input_hw=tuple(src_hw), patch_size=patch_size, pixel_shuffle=pixel_shuffle
        ), False
    w_in, h_in = input_wh
    H, W = src_hw
    if (h_in, w_in) == (H, W) or H * w_in == W * h_in:  # same aspect: no padding, a plain resize
        return PatchGeometry(input_hw=(h_in, w_in), patch_size=patch_size, pixel_shuffle=pixel_shuffle), False
    geom = PatchGeometry(
        input_hw=(h_in, w_in),
        patch_size=patch_size,
        src_hw=(H, W),
        resize="fit",
        pad="topleft",
        orientation="rot180",
        pixel_shuffle=pixel_shuffle,
    )
    return geom, True


HEATMAP_SUFFIX = ".heatmap"
VALID_SUFFIX = ".valid"


def gaze_valid_key(gaze_key: str) -> str | None:
    """The validity flag column of a heatmap column (`gaze.front.heatmap` -> `gaze.front.valid`), else None."""
    if gaze_key.endswith(HEATMAP_SUFFIX):
        return gaze_key[: -len(HEATMAP_SUFFIX)] + VALID_SUFFIX
    return None


def gaze_valid_flag(batch: dict, gaze_key: str) -> Tensor | None:
    """(B,) bool: the batch's validity flag of `gaze_key` (one bool per frame), or None where the key has no
    flag column or the batch lacks it."""
    key = gaze_valid_key(gaze_key)
    if key is None or key not in batch:
        return None
    flag = torch.as_tensor(batch[key]).detach().cpu()
    if flag.ndim <= 1:
        return flag.reshape(-1).bool()
    if flag[0].numel() != 1:
        raise GazeUsageError(
            f"gaze_key={gaze_key}",
            f"its flag column {key} holds shape {tuple(flag.shape[1:])} per frame, not one bool",
        )
    return flag.reshape(-1).bool()


POINT, HEATMAP, TOKENS = "point", "heatmap", "tokens"
ACCEPTED_SHAPES = (
    "(2,) a (u, v) point, (h, w) a heatmap over the frame or (n,) a distribution over n image tokens"
)


def gaze_kind(key: str, frame_shape: tuple[int, ...]) -> str:
    """POINT, HEATMAP or TOKENS for a gaze column whose value per frame has `frame_shape`; GazeUsageError naming
    the column, its shape and the accepted shapes for any other shape (e.g. (2, 8, 8): never guessed to be a
    history of two maps, since LeRobot loads gaze.* columns one frame per sample)."""
    s = tuple(int(d) for d in frame_shape)
    if s == (2,):
        return POINT
    if len(s) == 1 and s[0] >= 1:
        return TOKENS
    if len(s) == 2 and min(s) >= 1:
        return HEATMAP
    raise GazeUsageError(
        f"gaze_key={key}", f"the column's value per frame has shape {s}; accepted: {ACCEPTED_SHAPES}"
    )


def frame_valid(values: Tensor, kind: str) -> Tensor:
    """(N,) bool: which frames of `values` (N, *frame) carry usable gaze. POINT: finite and inside [0, 1]^2;
    HEATMAP: finite with a positive sum; TOKENS: a positive, finite mass after negatives are clipped to 0.
    The rule the training forward applies (gaze_distribution), also used to check a data set's column."""
    x = values.detach().float()
    flat = x.reshape(x.shape[0], -1)
    finite = torch.isfinite(flat).all(-1)
    if kind == POINT:
        return finite & (flat >= 0).all(-1) & (flat <= 1).all(-1)
    if kind == HEATMAP:
        return finite & (flat.nan_to_num(0.0).sum(-1) > 0)
    clipped = flat.clamp_min(0)  # NaN stays NaN, -inf becomes 0 (as the distribution below reads it)
    return torch.isfinite(clipped).all(-1) & (clipped.sum(-1) > 0)


def gaze_distribution(
    column: Tensor,
    geometry: PatchGeometry,
    flip: bool,
    sigma_frac: float,
    src_hw: tuple[int, int],
    eps: float = 1e-6,
    valid: Tensor | None = None,
    key: str = "gaze.point",
    frame_shape: tuple[int, ...] | None = None,
) -> tuple[Tensor, Tensor]:
    """(dist (B, n_tokens) float32, valid (B,) bool) from a batch of gaze column values (B, *frame_shape) (see
    module doc); `valid` (B,) bool, optional: the column's validity flag, ANDed with what the values themselves
    say. `frame_shape`: the data set's shape of the column `key` per frame (default: the batch's shape after B);
    a batch of another shape, or a frame shape gaze_kind refuses, raises GazeUsageError naming `key`."""
    got = tuple(column.shape[1:])
    if frame_shape is not None and got != tuple(frame_shape):
        raise GazeUsageError(
            f"gaze_key={key}",
            f"the batch holds values of shape {got} per frame but the data set declares {tuple(frame_shape)}",
        )
    dist, ok = _distribution(column, geometry, flip, sigma_frac, src_hw, eps, key, gaze_kind(key, got))
    if valid is not None:
        ok = ok & torch.as_tensor(valid, device=ok.device).reshape(ok.shape).bool()
        dist = torch.where(ok[:, None], dist, torch.full_like(dist, 1.0 / geometry.n_patches))
    return dist, ok


def _distribution(
    column: Tensor,
    geometry: PatchGeometry,
    flip: bool,
    sigma_frac: float,
    src_hw: tuple[int, int],
    eps: float,
    key: str,
    kind: str,
) -> tuple[Tensor, Tensor]:
    x = column.detach().float().cpu()
    n = geometry.n_patches
    valid = frame_valid(x, kind)
    if kind == POINT:
        H, W = src_hw
        h = 64
        w = max(1, round(h * W / H))
        heat, _ = heatmaps_from_points(x, size=(h, w), sigma=sigma_frac * h, valid=valid)
    elif kind == TOKENS:
        if x.shape[-1] != n:
            raise GazeUsageError(
                f"gaze_key={key}",
                f"the column holds {x.shape[-1]} values per frame, read as a distribution over image tokens, "
                f"but the camera has {n} ({geometry.grid_hw} grid); accepted: {ACCEPTED_SHAPES}",
            )
        x = x.clamp_min(0)
        mass = x.sum(-1, keepdim=True)
        dist = torch.where(valid[:, None], (x + eps) / (mass + n * eps), torch.full_like(x, 1.0 / n))
        return dist, valid
    else:
        heat = x.clamp_min(0).nan_to_num(0.0)
    dist, ok = patch_distribution(heat, geometry, valid, eps=eps)
    if flip:
        dist = dist.flip(-1)
    return dist, ok
