"""Temporal aggregation of per-frame gaze heatmaps over a window of frames.

For frame t the aggregated map is  G_t = sum_j w_j * P_{t+j} / sum_j w_j  over offsets j in [-past, future]
and only over frames that exist and are valid. At an episode's edges the window is truncated (no padding, no
wrap-around) and the remaining weights renormalised. A frame whose whole window has no valid frame is invalid.
The camera is assumed static between frames of the window (the warp of the method is the identity).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Literal, get_args

import torch
from torch import Tensor

from gazereg.heatmaps import as_tensor, check_heatmaps
from gazereg.runtime.config import Validated, require_choice, require_number

Kernel = Literal["uniform", "gaussian", "exponential"]


@dataclass(frozen=True)
class AggregationConfig(Validated):
    """Window of `past` frames before and `future` frames after t (centred: both; causal: future=0;
    future-only: past=0). Kernel weights by offset j: uniform 1; gaussian exp(-j^2 / (2 sigma^2));
    exponential exp(-|j| / tau). Checked when built (`Validated`): a bad value is a UsageError naming the
    option, e.g. `--aggregation.past must be an integer >= 0, got -1`."""

    OPTION_PREFIX: ClassVar[str] = "aggregation."

    past: int = 2
    future: int = 2
    kernel: Kernel = "uniform"
    sigma: float = 2.0  # frames, for the gaussian kernel
    tau: float = 2.0  # frames, for the exponential kernel

    def validate(self, prefix: str) -> None:
        """UsageError naming the first bad option (`prefix`: "aggregation." on the command line)."""
        for name in ("past", "future"):
            require_number(getattr(self, name), prefix + name, 0, integer=True)
        require_choice(self.kernel, prefix + "kernel", get_args(Kernel))
        for name in ("sigma", "tau"):
            require_number(getattr(self, name), prefix + name, 0, open_low=True)

    def weights(self) -> Tensor:
        """(past + future + 1,) weights for offsets -past..future."""
        j = torch.arange(-self.past, self.future + 1, dtype=torch.float64)
        if self.kernel == "uniform":
            w = torch.ones_like(j)
        elif self.kernel == "gaussian":
            w = torch.exp(-(j**2) / (2 * self.sigma**2))
        else:
            w = torch.exp(-j.abs() / self.tau)
        return w

    @classmethod
    def none(cls) -> AggregationConfig:
        return cls(past=0, future=0)


def aggregate(
    heatmaps: Tensor, valid: Tensor | None = None, cfg: AggregationConfig | None = None
) -> tuple[Tensor, Tensor]:
    """Aggregate an episode's per-frame heatmaps over time.

    Args:
        heatmaps: (T, H, W) non-negative, finite; each valid frame sums to 1.
        valid: (T,) bool; default: frames that are not all zero.
        cfg: the window and kernel (default AggregationConfig()).

    Returns:
        aggregated (T, H, W) float32, each valid frame summing to 1 (invalid frames all zero); valid (T,) bool.
    """
    cfg = cfg or AggregationConfig()
    heatmaps = as_tensor(heatmaps, torch.float32)
    if heatmaps.ndim != 3:
        raise ValueError(f"heatmaps must be (T, H, W), got {tuple(heatmaps.shape)}")
    T = heatmaps.shape[0]
    if T == 0:
        raise ValueError("cannot aggregate an empty episode (T = 0)")
    ok = check_heatmaps(heatmaps, valid)
    totals = heatmaps.flatten(1).sum(1).clamp_min(1e-30)
    maps = torch.where(
        ok[:, None, None], heatmaps / totals[:, None, None], torch.zeros_like(heatmaps)
    ).double()
    w = cfg.weights()
    out = torch.zeros_like(maps)
    norm = torch.zeros(T, dtype=torch.float64)
    okd = ok.double()
    for k, j in enumerate(range(-cfg.past, cfg.future + 1)):
        # target frames t whose source t + j lies inside the episode
        lo, hi = max(0, -j), min(T, T - j)
        if lo >= hi:
            continue
        src = slice(lo + j, hi + j)
        out[lo:hi] += w[k] * maps[src]
        norm[lo:hi] += w[k] * okd[src]
    out_ok = norm > 0
    out = torch.where(
        out_ok[:, None, None], out / norm.clamp_min(1e-300)[:, None, None], torch.zeros_like(out)
    )
    return out.float(), out_ok


def window_length(cfg: AggregationConfig) -> int:
    return cfg.past + cfg.future + 1


def effective_frames(cfg: AggregationConfig) -> float:
    """Kish effective number of frames in a full window: (sum w)^2 / sum w^2."""
    w = cfg.weights()
    return float(w.sum() ** 2 / (w**2).sum()) if len(w) else math.nan
