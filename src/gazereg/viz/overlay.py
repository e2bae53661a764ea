"""Heatmap overlays on frames (numpy in, numpy out; matplotlib only for its colour map, imported lazily)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gazereg.runtime.io import atomic_path


def colorize(heat: np.ndarray, cmap: str = "inferno") -> np.ndarray:
    """(H, W) non-negative map -> (H, W, 3) uint8 colours, scaled so the map's maximum is the top colour."""
    from matplotlib import colormaps

    h = np.asarray(heat, dtype=np.float64)
    h = h / h.max() if h.max() > 0 else h
    return (colormaps[cmap](h)[..., :3] * 255).astype(np.uint8)


def overlay(frame: np.ndarray, heat: np.ndarray, alpha: float = 0.55, cmap: str = "inferno") -> np.ndarray:
    """Blend a heatmap (any (h, w), resized by nearest neighbour) over an RGB uint8 frame (H, W, 3).

    The heat is min-max scaled and its opacity follows its value, so cold regions leave the frame visible
    and a uniform map adds nothing."""
    H, W = frame.shape[:2]
    h = np.asarray(heat, dtype=np.float64)
    if h.shape != (H, W):
        rows = (np.arange(H) * h.shape[0] // H).clip(0, h.shape[0] - 1)
        cols = (np.arange(W) * h.shape[1] // W).clip(0, h.shape[1] - 1)
        h = h[rows][:, cols]
    span = h.max() - h.min()
    h = (
        (h - h.min()) / span if span > 1e-12 * max(h.max(), 1e-30) else np.zeros_like(h)
    )  # uniform: no overlay
    a = (alpha * np.sqrt(h))[..., None]
    out = (1 - a) * frame.astype(np.float64) + a * colorize(h, cmap).astype(np.float64)
    return out.clip(0, 255).astype(np.uint8)


def write_gif(path: str | Path, frames: list[np.ndarray], fps: int = 20) -> Path:
    """Write frames (H, W, 3) uint8 as an animated GIF, atomically."""
    from PIL import Image

    if not frames:
        raise ValueError("no frames to write")
    imgs = [Image.fromarray(np.asarray(f)) for f in frames]
    with atomic_path(path) as tmp:
        imgs[0].save(
            tmp, format="GIF", save_all=True, append_images=imgs[1:], duration=int(1000 / fps), loop=0
        )
    return Path(path)
