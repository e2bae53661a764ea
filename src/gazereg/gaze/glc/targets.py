"""GLC's ground truth: one Gaussian heatmap per gaze point on the model's output grid.

The same maps are the training targets (`gazereg.training.glc`) and, binarised, the ground truth of the
GLC paper's metrics (`gazereg.gaze.glc.metrics`). They follow the official code, not
`gazereg.heatmaps.heatmaps_from_points` (the priors' maps): the centre is the pixel
`(round(v*h), round(u*w))` rather than a continuous position over cell centres, the Gaussian is cut to a
19-pixel window at 64 px, and a missing point gives a uniform map rather than an all-zero one.
"""

from __future__ import annotations

import torch

KERNEL_SIZE_AT_64 = 19
SIGMA_AT_64 = 3.2  # OpenCV's default for a 19-tap kernel: 0.3 * ((19 - 1) / 2 - 1) + 0.8


def gaze_target_maps(
    points: torch.Tensor,
    valid: torch.Tensor | None,
    size: tuple[int, int],
    kernel_size: int | None = None,
    sigma: float | None = None,
) -> torch.Tensor:
    """Gaussian target heatmaps, one per gaze point (the official GLC targets, scaled to `size`).

    Args:
        points: `(..., 2)` normalised `(u, v)`; the centre pixel is `(round(v*h), round(u*w))`.
        valid: `(...)` bool; None = all valid.
        size: `(h, w)` of the map in pixels (64x64 for the full model).
        kernel_size: odd window size in pixels; default 19 at 64 px, scaled (`2*round(9*h/64)+1`).
        sigma: Gaussian sigma in pixels; default `3.2 * h / 64`.

    Returns:
        float32 `(..., h, w)`, each map summing to 1: the Gaussian cut to the window and to the frame,
        renormalised; uniform `1/(h*w)` where the point is invalid, outside [0, 1]^2, or its window
        degenerates at a border.
    """
    h, w = size
    if kernel_size is None:
        kernel_size = 2 * max(1, round((KERNEL_SIZE_AT_64 - 1) / 2 * h / 64)) + 1
    if sigma is None:
        sigma = SIGMA_AT_64 * h / 64
    r = (kernel_size - 1) // 2
    lead = points.shape[:-1]
    pts = points.reshape(-1, 2).float()
    ok = torch.ones(pts.shape[0], dtype=torch.bool) if valid is None else valid.reshape(-1).bool().clone()
    ok &= ((pts >= 0) & (pts <= 1)).all(-1) & torch.isfinite(pts).all(-1)
    pts = torch.where(ok[:, None], pts, torch.zeros_like(pts))
    cx = torch.round(pts[:, 0] * w)  # round half to even, like Python's round
    cy = torch.round(pts[:, 1] * h)
    xs = torch.arange(w, dtype=torch.float32)
    ys = torch.arange(h, dtype=torch.float32)
    dx = xs[None, :] - cx[:, None]  # (F, w)
    dy = ys[None, :] - cy[:, None]  # (F, h)
    gx = torch.exp(-0.5 * (dx / sigma) ** 2) * (dx.abs() <= r)
    gy = torch.exp(-0.5 * (dy / sigma) ** 2) * (dy.abs() <= r)
    # the official code leaves a window of width or height 1 empty (left >= right or top >= bottom)
    ok &= ((dx.abs() <= r).sum(-1) > 1) & ((dy.abs() <= r).sum(-1) > 1)
    maps = gy[:, :, None] * gx[:, None, :]
    maps = maps / maps.sum(dim=(1, 2), keepdim=True).clamp_min(1e-30)
    maps = torch.where(ok[:, None, None], maps, torch.full_like(maps, 1.0 / (h * w)))
    return maps.reshape(*lead, h, w)
