"""Photometric augmentation of a training batch's frames: brightness, contrast and colour (saturation) jitter,
for every policy (it changes pixel values, never where they are, so the gaze targets stay as they are).

    aug = PhotometricConfig(brightness=0.3, contrast=0.3, saturation=0.3)   # --train.photometric.brightness 0.3 ...
    batch = photometric(batch, aug, generator)      # every `image.<camera>` (B, H, W, 3) in 0..255 -> float32

Per frame, in this order, each factor drawn uniformly from [1 - s, 1 + s] by `generator` (no global RNG, so a
run stays reproducible and resumable): brightness scales the pixel values; contrast blends the frame with its
mean grey level; saturation blends each pixel with its own grey level (ITU-R BT.601 luma); the result is
clipped to 0..255. A camera's frames of one sample are jittered independently of the other cameras'. All zero
(the default) leaves the batch untouched and draws nothing, so runs without it are bit for bit what they were.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor

from gazereg.runtime.config import Validated, require_number

LUMA = (0.299, 0.587, 0.114)
"""ITU-R BT.601 weights of R, G, B in a pixel's grey level"""


@dataclass(frozen=True)
class PhotometricConfig(Validated):
    """The jitter strengths: each factor is drawn from [1 - s, 1 + s] per frame (0: off; below 1)."""

    OPTION_PREFIX: ClassVar[str] = "photometric."

    brightness: float = 0.0
    contrast: float = 0.0
    saturation: float = 0.0

    @property
    def active(self) -> bool:
        return self.brightness > 0 or self.contrast > 0 or self.saturation > 0

    def validate(self, prefix: str) -> None:
        for name in ("brightness", "contrast", "saturation"):
            require_number(getattr(self, name), f"{prefix}{name}", 0, 1, open_high=True)


def _factors(n: int, strength: float, generator: torch.Generator, device: torch.device) -> Tensor:
    """(n, 1, 1, 1) factors uniform in [1 - strength, 1 + strength]."""
    u = torch.rand(n, generator=generator, device=generator.device).to(device)
    return (1 + strength * (2 * u - 1)).view(n, 1, 1, 1)


def grey(frames: Tensor) -> Tensor:
    """(..., H, W, 3) -> (..., H, W, 1): each pixel's grey level (`LUMA`)."""
    w = torch.tensor(LUMA, dtype=frames.dtype, device=frames.device)
    return (frames * w).sum(-1, keepdim=True)


def jitter(frames: Tensor, cfg: PhotometricConfig, generator: torch.Generator) -> Tensor:
    """(B, H, W, 3) frames in 0..255 (any dtype) -> float32 jittered frames in 0..255 (module docstring)."""
    x = frames.float()
    B = x.shape[0]
    if cfg.brightness > 0:
        x = x * _factors(B, cfg.brightness, generator, x.device)
    if cfg.contrast > 0:
        mean = grey(x).mean(dim=(1, 2, 3), keepdim=True)  # (B, 1, 1, 1)
        x = mean + (x - mean) * _factors(B, cfg.contrast, generator, x.device)
    if cfg.saturation > 0:
        g = grey(x)
        x = g + (x - g) * _factors(B, cfg.saturation, generator, x.device)
    return x.clamp(0.0, 255.0)


def photometric(
    batch: Mapping[str, Tensor], cfg: PhotometricConfig, generator: torch.Generator
) -> dict[str, Tensor]:
    """`batch` with every `image.<camera>` frame jittered (cameras in sorted order); unchanged when `cfg` is off."""
    out = dict(batch)
    if not cfg.active:
        return out
    for key in sorted(k for k in batch if k.startswith("image.")):
        frames = batch[key]
        if frames.ndim != 4 or frames.shape[-1] != 3:
            raise ValueError(
                f"{key}: photometric augmentation takes (B, H, W, 3) frames, got {tuple(frames.shape)}"
            )
        out[key] = jitter(frames, cfg, generator)
    return out
