"""Heatmaps -> distributions over a policy's image patches, through the policy's own image geometry.

The geometry owns every step between a stored frame and the policy's input tokens, in this order:
  1. orientation: none | rot180 | hflip | vflip (e.g. LIBERO renders upside down);
  2. crop_box: an optional (u0, v0, u1, v1) window of the oriented frame, normalised;
  3. resize to the policy's input (H_in, W_in): `stretch` (ignore aspect), `fit` (keep aspect, letterbox;
     `pad` says where the image sits: `topleft` with padding bottom/right as transformers' PI0 processor,
     `bottomright` with padding top/left as LeRobot's `resize_with_pad` for SmolVLA and pi0, or `centre`),
     or `cover` (keep aspect, scale to cover, centre crop);
  4. patches of `patch_size` pixels, row-major; `pixel_shuffle` s merges s x s patches into one token.
The same object maps gaze points, heatmaps and attention maps, so frames and gaze can never disagree.

A heatmap is treated as a piecewise-constant density over the frame; each patch receives the exact area
integral of the density over its pixels (separable overlap matrices), mass falling outside the input
(cropped away) is dropped, padding receives none, then an epsilon floor and renormalisation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from torch import Tensor

from gazereg.heatmaps import as_tensor, check_heatmaps

Orientation = Literal["none", "rot180", "hflip", "vflip"]


@dataclass(frozen=True)
class PatchGeometry:
    """Image geometry of one camera as one policy sees it. Sizes are (height, width) in pixels."""

    input_hw: tuple[int, int]
    patch_size: int
    src_hw: tuple[int, int] | None = None  # stored frame size; needed for fit/cover (aspect ratio)
    resize: Literal["stretch", "fit", "cover"] = "stretch"
    pad: Literal["topleft", "centre", "bottomright"] = "centre"
    """where a `fit` image sits inside the padded input"""
    orientation: Orientation = "none"
    crop_box: tuple[float, float, float, float] | None = None
    pixel_shuffle: int = 1

    def __post_init__(self) -> None:
        H, W = self.input_hw
        step = self.patch_size * self.pixel_shuffle
        if self.patch_size <= 0 or self.pixel_shuffle <= 0:
            raise ValueError(
                f"patch_size and pixel_shuffle must be positive, got {self.patch_size}, {self.pixel_shuffle}"
            )
        if H % step or W % step:
            raise ValueError(
                f"input {H}x{W} px is not divisible into tokens of {self.patch_size} px patches x pixel_shuffle "
                f"{self.pixel_shuffle} (= {step} px): the patch grid does not fit the image geometry"
            )
        if self.pad not in ("topleft", "centre", "bottomright"):
            raise ValueError(f"pad must be topleft, centre or bottomright, got {self.pad!r}")
        if self.resize != "stretch" and self.src_hw is None:
            raise ValueError(
                f"resize={self.resize!r} keeps the aspect ratio and needs src_hw (the stored frame size)"
            )
        if self.crop_box is not None:
            u0, v0, u1, v1 = self.crop_box
            if not (0 <= u0 < u1 <= 1 and 0 <= v0 < v1 <= 1):
                raise ValueError(
                    f"crop_box must satisfy 0 <= u0 < u1 <= 1 and 0 <= v0 < v1 <= 1, got {self.crop_box}"
                )

    @property
    def grid_hw(self) -> tuple[int, int]:
        step = self.patch_size * self.pixel_shuffle
        return self.input_hw[0] // step, self.input_hw[1] // step

    @property
    def n_patches(self) -> int:
        h, w = self.grid_hw
        return h * w

    def check_grid(self, grid_hw: tuple[int, int]) -> None:
        """Raise if a model's patch grid differs from this geometry's."""
        if tuple(grid_hw) != self.grid_hw:
            raise ValueError(
                f"model patch grid {tuple(grid_hw)} does not match the image geometry's grid {self.grid_hw} ({self})"
            )

    # ----- the affine map, per axis: input_px = scale * x + offset, x normalised in the oriented, cropped frame
    def _axis(self, axis: int) -> tuple[float, float, float, float, bool]:
        """(scale, offset, crop_lo, crop_hi, flipped) for axis 0 (v, rows) or 1 (u, columns)."""
        n_in = self.input_hw[axis]
        flipped = (
            self.orientation == "rot180"
            or (self.orientation == "vflip" and axis == 0)
            or (self.orientation == "hflip" and axis == 1)
        )
        lo, hi = (
            (0.0, 1.0)
            if self.crop_box is None
            else ((self.crop_box[1], self.crop_box[3]) if axis == 0 else (self.crop_box[0], self.crop_box[2]))
        )
        if self.resize == "stretch":
            return n_in / (hi - lo), -lo * n_in / (hi - lo), lo, hi, flipped
        assert self.src_hw is not None
        cw = [
            (self.crop_box[3] - self.crop_box[1]) if self.crop_box else 1.0,
            (self.crop_box[2] - self.crop_box[0]) if self.crop_box else 1.0,
        ]
        content = [self.src_hw[0] * cw[0], self.src_hw[1] * cw[1]]  # cropped frame size in source pixels
        ratios = [self.input_hw[0] / content[0], self.input_hw[1] / content[1]]
        s = min(ratios) if self.resize == "fit" else max(ratios)
        size_px = content[axis] * s  # size of the content in input pixels along this axis
        if self.resize == "fit" and self.pad == "topleft":
            off = 0.0
        elif self.resize == "fit" and self.pad == "bottomright":
            off = n_in - size_px
        else:
            off = (n_in - size_px) / 2
        scale = size_px / (hi - lo)
        return scale, off - lo * scale, lo, hi, flipped

    def map_points(self, uv: Tensor | np.ndarray) -> Tensor:
        """Normalised (u, v) in the stored frame -> normalised (u, v) in the policy's input image.

        Points that leave the input (cropped away) come out outside [0, 1]."""
        uv = as_tensor(uv, torch.float64)
        out = torch.empty_like(uv)
        for axis, comp in ((1, 0), (0, 1)):
            scale, offset, _, _, flipped = self._axis(axis)
            x = 1 - uv[..., comp] if flipped else uv[..., comp]
            out[..., comp] = (scale * x + offset) / self.input_hw[axis]
        return out.float()

    def patch_index(self, uv: Tensor | np.ndarray) -> Tensor:
        """Row-major token index holding each stored-frame point (..., 2) -> (...) long; -1 outside the input."""
        p = self.map_points(uv)
        gh, gw = self.grid_hw
        col = torch.floor(p[..., 0] * gw).long()
        row = torch.floor(p[..., 1] * gh).long()
        inside = (p >= 0).all(-1) & (p < 1).all(-1)
        return torch.where(inside, row * gw + col, torch.full_like(row, -1))

    def overlap(self, n_src: int, axis: int) -> Tensor:
        """(grid_n, n_src) float64: fraction of source cell k (along this axis) that lands in token i."""
        scale, offset, _, _, flipped = self._axis(axis)
        k = torch.arange(n_src, dtype=torch.float64)
        a, b = k / n_src, (k + 1) / n_src
        if flipped:
            a, b = 1 - b, 1 - a
        lo, hi = scale * a + offset, scale * b + offset  # cell extent in input pixels
        step = self.patch_size * self.pixel_shuffle
        g = torch.arange(self.grid_hw[axis], dtype=torch.float64)
        p_lo, p_hi = g * step, (g + 1) * step
        inter = (torch.minimum(hi[None], p_hi[:, None]) - torch.maximum(lo[None], p_lo[:, None])).clamp_min(0)
        return inter / (hi - lo)[None]


def patch_distribution(
    heatmaps: Tensor | np.ndarray,
    geometry: PatchGeometry,
    valid: Tensor | np.ndarray | None = None,
    eps: float = 1e-6,
) -> tuple[Tensor, Tensor]:
    """Area-sum heatmaps onto the policy's patch grid.

    Args:
        heatmaps: (..., h, w) non-negative densities over the stored frame (any resolution).
        geometry: the camera's image geometry for this policy.
        valid: (...) bool, default all True.
        eps: floor added to every patch before renormalising (keeps log terms finite).

    Returns:
        dist (..., n_patches) float32, row-major over geometry.grid_hw, summing to 1 (uniform where invalid);
        valid (...) bool: False where the input was invalid or all its mass fell outside the input image.
    """
    heat = as_tensor(heatmaps, torch.float64)
    if heat.ndim < 2:
        raise ValueError(f"heatmaps must be (..., h, w), got {tuple(heat.shape)}")
    if eps < 0:
        raise ValueError(f"eps must be >= 0, got {eps}")
    ok = check_heatmaps(heat, valid)
    h, w = heat.shape[-2:]
    my, mx = geometry.overlap(h, 0), geometry.overlap(w, 1)
    pooled = torch.einsum("ik,...kl,jl->...ij", my, heat, mx).flatten(-2)  # (..., n_patches)
    mass = pooled.sum(-1)
    ok = ok & (mass > 1e-12 * heat.flatten(-2).sum(-1).clamp_min(1e-300))
    pooled = pooled / mass.clamp_min(1e-300)[..., None] + eps
    dist = pooled / pooled.sum(-1, keepdim=True)
    n = geometry.n_patches
    dist = torch.where(ok[..., None], dist, torch.full_like(dist, 1.0 / n))
    return dist.float(), ok


def grid_to_image(dist: Tensor | np.ndarray, geometry: PatchGeometry, size: tuple[int, int]) -> Tensor:
    """Spread a patch distribution (..., n_patches) back onto the stored frame as a (..., H, W) density
    (for overlays): each frame cell takes its patch's mass divided by the patch's area; summing to 1 over
    the visible part."""
    dist = as_tensor(dist, torch.float64)
    H, W = size
    my, mx = geometry.overlap(H, 0), geometry.overlap(W, 1)  # (gh, H), (gw, W)
    gh, gw = geometry.grid_hw
    grid = dist.reshape(*dist.shape[:-1], gh, gw)
    area = my.sum(1)[:, None] * mx.sum(1)[None, :]  # source cells per patch
    density = grid / area.clamp_min(1e-12)
    out = torch.einsum("ik,...ij,jl->...kl", my, density, mx)
    return (out / out.flatten(-2).sum(-1).clamp_min(1e-300)[..., None, None]).float()


def patch_distributions(
    heatmaps: dict[str, Tensor], geometries: dict[str, PatchGeometry], eps: float = 1e-6
) -> dict[str, tuple[Tensor, Tensor]]:
    """Several cameras: {camera: heatmaps (..., h, w)} -> {camera: (dist (..., n_patches), valid (...))}."""
    missing = sorted(set(heatmaps) - set(geometries))
    if missing:
        raise KeyError(
            f"no image geometry for camera(s) {missing}; geometries exist for {sorted(geometries)}"
        )
    return {cam: patch_distribution(h, geometries[cam], eps=eps) for cam, h in heatmaps.items()}
