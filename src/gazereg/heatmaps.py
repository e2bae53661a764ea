"""Gaussian heatmaps from gaze points.

Coordinates are (u, v) normalised to [0, 1] in the image as the policy sees it: u to the right, v downward.
A heatmap cell (i, j) covers the pixel square [j, j+1) x [i, i+1), so its centre is at
((j + 0.5) / W, (i + 0.5) / H) in normalised coordinates.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor


def as_tensor(x: Tensor | np.ndarray, dtype: torch.dtype | None = None) -> Tensor:
    """A tensor view of x (copied when x is a read-only array, e.g. a memory-mapped episode)."""
    if isinstance(x, Tensor):
        return x if dtype is None else x.to(dtype)
    if isinstance(x, np.ndarray) and not x.flags.writeable:
        x = np.array(x)
    return torch.as_tensor(x, dtype=dtype)


def heatmaps_from_points(
    points: Tensor | np.ndarray,
    size: tuple[int, int],
    sigma: float,
    valid: Tensor | np.ndarray | None = None,
    truncate: float | None = None,
) -> tuple[Tensor, Tensor]:
    """Gaussian heatmaps centred on gaze points.

    Args:
        points: (..., 2) normalised (u, v); NaN marks a missing point.
        size: (H, W) of each heatmap in cells.
        sigma: standard deviation in cells (GLC's ground truth: 3.2 on a 64x64 map).
        valid: (...) bool; False marks a frame without usable gaze. Default: all True.
        truncate: cut the Gaussian at this many cells from the centre in each axis (GLC: a 19x19 kernel is
            truncate=9); None keeps the full Gaussian.

    Returns:
        heatmaps (..., H, W) float32, each valid one non-negative and summing to 1; invalid ones are all zero.
        valid (...) bool: the input mask AND the point being finite and inside [0, 1]^2.
    """
    H, W = size
    if H <= 0 or W <= 0:
        raise ValueError(f"heatmap size must be positive, got {size}")
    if not sigma > 0:
        raise ValueError(f"sigma must be > 0 cells, got {sigma}")
    pts = as_tensor(points, torch.float32)
    if pts.shape[-1] != 2:
        raise ValueError(f"points must have shape (..., 2), got {tuple(pts.shape)}")
    ok = torch.isfinite(pts).all(-1) & (pts >= 0).all(-1) & (pts <= 1).all(-1)
    if valid is not None:
        v = as_tensor(valid, torch.bool)
        if v.shape != ok.shape:
            raise ValueError(f"valid has shape {tuple(v.shape)}, points need {tuple(ok.shape)}")
        ok = ok & v
    safe = torch.where(ok[..., None], pts, torch.full_like(pts, 0.5))
    cx = safe[..., 0, None] * W - 0.5  # centre in cell-index units
    cy = safe[..., 1, None] * H - 0.5
    xs = torch.arange(W, dtype=torch.float32)
    ys = torch.arange(H, dtype=torch.float32)
    dx2 = (xs - cx) ** 2  # (..., W)
    dy2 = (ys - cy) ** 2  # (..., H)
    gx = torch.exp(-dx2 / (2 * sigma**2))
    gy = torch.exp(-dy2 / (2 * sigma**2))
    if truncate is not None:
        gx = gx * ((xs - cx.round()).abs() <= truncate)
        gy = gy * ((ys - cy.round()).abs() <= truncate)
    maps = gy[..., :, None] * gx[..., None, :]  # separable: (..., H, W)
    total = maps.sum(dim=(-2, -1), keepdim=True)
    ok = ok & (total[..., 0, 0] > 0)
    maps = torch.where(ok[..., None, None], maps / total.clamp_min(1e-30), torch.zeros_like(maps))
    return maps, ok


def uniform_heatmaps(shape: tuple[int, ...], size: tuple[int, int]) -> Tensor:
    """Uniform heatmaps (*shape, H, W), each summing to 1."""
    H, W = size
    return torch.full((*shape, H, W), 1.0 / (H * W))


def check_heatmaps(heatmaps: Tensor, valid: Tensor | None = None, name: str = "heatmaps") -> Tensor:
    """Validate heatmaps (..., H, W): returns a validity mask (...) that is False where a map is all zero.

    NaN, inf or negative values are errors (they would silently corrupt every downstream sum).
    """
    if not torch.isfinite(heatmaps).all():
        raise ValueError(f"{name} contain NaN or inf")
    if (heatmaps < 0).any():
        raise ValueError(f"{name} contain negative values (min {heatmaps.min().item():.3g})")
    ok = heatmaps.flatten(-2).sum(-1) > 0
    return ok if valid is None else ok & as_tensor(valid, torch.bool)
