"""Gaze sources that need no model and no simulator: `uniform` and bottom-up `saliency`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch
import torch.nn.functional as F

from gazereg.data.store import Episode
from gazereg.gaze.sources import register_gaze_source
from gazereg.gaze.sources.params import GazeSourceParams
from gazereg.runtime.errors import UsageError


@dataclass(frozen=True)
class UniformParams(GazeSourceParams):
    """The uniform source has no parameters."""

    name: ClassVar[str] = "uniform"


@register_gaze_source(UniformParams)
class UniformGaze:
    """Every frame uniform: the 'no information' control (pushes attention to spread evenly)."""

    name = "uniform"

    def __init__(self, params: UniformParams = UniformParams()):
        self.params = params

    def __call__(self, episode: Episode, camera: str, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        T = episode.length
        return np.full((T, *size), 1.0 / (size[0] * size[1]), np.float32), np.ones(T, bool)

    def describe(self) -> dict[str, Any]:
        return {"name": self.name}


@dataclass(frozen=True)
class SaliencyParams(GazeSourceParams):
    """`work_size`: side of the square image the contrast is computed on, pixels; `centre`, `surround`,
    `blur_sigma`, `centre_sigma`: Gaussian standard deviations as fractions of `work_size` (0 disables the
    centre bias)."""

    name: ClassVar[str] = "saliency"
    work_size: int = 64
    centre: float = 0.02
    surround: float = 0.15
    blur_sigma: float = 0.03
    centre_sigma: float = 0.0

    def __post_init__(self) -> None:
        if self.work_size < 8:
            raise UsageError(f"work_size must be >= 8 px, got {self.work_size}")
        if not 0 <= self.centre < self.surround:
            raise UsageError(f"need 0 <= centre < surround, got {self.centre}, {self.surround}")


@register_gaze_source(SaliencyParams)
class ContrastSaliency:
    """Bottom-up image saliency: centre-surround colour contrast (a difference of Gaussians, Itti-style)
    with an optional centre bias.

    Per frame, on the RGB image resized to `work_size`: sum over channels of
    (blur(c, centre_px) - blur(c, surround_px))^2, blurred with `blur_sigma`, times a centre Gaussian of
    `centre_sigma` (fractions of the width; 0 disables), resized to the output grid by area."""

    name = "saliency"

    def __init__(self, params: SaliencyParams = SaliencyParams()):
        self.params = params
        self.work_size, self.centre, self.surround = params.work_size, params.centre, params.surround
        self.blur_sigma, self.centre_sigma = params.blur_sigma, params.centre_sigma

    def describe(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "work_size": self.work_size,
            "centre": self.centre,
            "surround": self.surround,
            "blur_sigma": self.blur_sigma,
            "centre_sigma": self.centre_sigma,
        }

    def __call__(self, episode: Episode, camera: str, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        frames = torch.as_tensor(np.asarray(episode.frames[camera]), dtype=torch.float32)  # (T, H, W, 3)
        s = self.work_size
        img = F.interpolate(
            frames.permute(0, 3, 1, 2) / 255.0, size=(s, s), mode="area"
        ).double()  # (T, 3, s, s)
        T = img.shape[0]
        flat = img.reshape(T * 3, s, s)
        dog = _gaussian_blur(flat, self.centre * s) - _gaussian_blur(flat, self.surround * s)
        sal = _gaussian_blur(dog.pow(2).reshape(T, 3, s, s).sum(1), self.blur_sigma * s)
        if self.centre_sigma > 0:
            c = (torch.arange(s, dtype=torch.float64) + 0.5) / s - 0.5
            sal = sal * torch.exp(-(c[:, None] ** 2 + c[None, :] ** 2) / (2 * self.centre_sigma**2))
        out = F.interpolate(sal[:, None].float(), size=size, mode="area")[:, 0].clamp_min(0)
        total = out.flatten(1).sum(1)
        valid = torch.isfinite(total) & (total > 0)
        out = torch.where(
            valid[:, None, None], out / total.clamp_min(1e-30)[:, None, None], torch.zeros_like(out)
        )
        return out.numpy(), valid.numpy()


def _gaussian_blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of (T, H, W) with reflect padding; sigma in pixels (<= 0: no blur)."""
    if sigma <= 0:
        return x
    r = max(1, int(3 * sigma))
    k = torch.exp(-(torch.arange(-r, r + 1, dtype=x.dtype) ** 2) / (2 * sigma**2))
    k = k / k.sum()
    y = F.pad(x[:, None], (r, r, 0, 0), mode="reflect")
    y = F.conv2d(y, k.view(1, 1, 1, -1))
    y = F.pad(y, (0, 0, r, r), mode="reflect")
    return F.conv2d(y, k.view(1, 1, -1, 1))[:, 0]
