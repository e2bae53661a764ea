"""Gaze columns of a LeRobot data set -> gaze distributions over SmolVLA's image tokens of one camera.

A column may hold, per frame:
- a gaze point (u, v) in [0, 1] (u right, v down, in the stored frame): a Gaussian heatmap around it
  (sigma a fraction of the frame height), NaN or out-of-frame -> no gaze (invalid frame);
- a heatmap (h, w) over the stored frame, at any resolution: pooled onto the token grid (what
  `gazereg import write-gaze` writes as `gaze.<camera>.heatmap`, with its flag `gaze.<camera>.valid`);
- a distribution over the camera's tokens (n_tokens,) already on the token grid: used as it is.
A validity column next to it (`gaze_valid_key`: `gaze.<camera>.valid` for `gaze.<camera>.heatmap`) masks frames
further: a frame counts only where the column is valid AND the flag is true.

The stored frame reaches SmolVLA through `resize_with_pad` (keep the aspect ratio, pad on the LEFT and TOP,
content at the bottom-right) to `resize_imgs_with_padding` (width, height), then SigLIP patches and the
connector's pixel shuffle. gazereg's PatchGeometry places fitted content at the top-left ('topleft') or the
centre, so the bottom-right placement is expressed exactly as: rotate the frame by 180 degrees, place it top-left,
pool, and rotate the token grid back (reverse the row-major vector).
"""

from __future__ import annotations

import torch
from torch import Tensor

from gazereg.gaze.heatmaps import heatmaps_from_points
from gazereg.patches import PatchGeometry, patch_distribution


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
    """(B,) bool: the batch's validity flag of `gaze_key` (the current frame where it has a history), or None
    where the key has no flag column or the batch lacks it."""
    key = gaze_valid_key(gaze_key)
    if key is None or key not in batch:
        return None
    flag = torch.as_tensor(batch[key]).detach().cpu()
    return (flag.reshape(-1) if flag.ndim <= 1 else flag.reshape(flag.shape[0], -1)[:, -1]).bool()


def gaze_distribution(
    column: Tensor,
    geometry: PatchGeometry,
    flip: bool,
    sigma_frac: float,
    src_hw: tuple[int, int],
    eps: float = 1e-6,
    valid: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """(dist (B, n_tokens) float32, valid (B,) bool) from a batch of gaze column values (see module doc);
    `valid` (B,) bool, optional: the column's validity flag, ANDed with what the values themselves say."""
    dist, ok = _distribution(column, geometry, flip, sigma_frac, src_hw, eps)
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
) -> tuple[Tensor, Tensor]:
    x = column.detach().float().cpu()
    n = geometry.n_patches
    history = (x.ndim == 3 and x.shape[-1] == 2) or x.ndim == 4  # (B, T, 2) points or (B, T, h, w) maps
    if history:  # with observation history: the current frame
        x = x[:, -1]
    if x.ndim == 2 and x.shape[-1] == 2:
        H, W = src_hw
        h = 64
        w = max(1, round(h * W / H))
        heat, valid = heatmaps_from_points(x, size=(h, w), sigma=sigma_frac * h)
    elif x.ndim == 2 and x.shape[-1] == n:
        x = x.clamp_min(0)
        mass = x.sum(-1, keepdim=True)
        valid = torch.isfinite(x).all(-1) & (mass[:, 0] > 0)
        dist = torch.where(valid[:, None], (x + eps) / (mass + n * eps), torch.full_like(x, 1.0 / n))
        return dist, valid
    elif x.ndim == 3:
        heat, valid = x.clamp_min(0).nan_to_num(0.0), torch.isfinite(x).all((-1, -2)) & (x.sum((-1, -2)) > 0)
    else:
        raise ValueError(
            f"gaze column values have shape {tuple(column.shape)}: expected (B, 2) points, (B, h, w) heatmaps or "
            f"(B, {n}) distributions over the camera's {geometry.grid_hw} token grid"
        )
    dist, ok = patch_distribution(heat, geometry, valid, eps=eps)
    if flip:
        dist = dist.flip(-1)
    return dist, ok
