"""The "mass" variant of the gaze term: supervise where the attention goes AND how much of it goes to the image.

The plain term compares the gaze with the attention renormalised over the camera's patches, so it can be met by
barely attending to the image at all (the renormalised distribution is then fitted from a tiny mass). The mass
variant compares N + 1 bins instead: the attention to each patch as it is (not renormalised) plus one bin for
everything else (text, state, other cameras), against the target `m * gaze` on the patches and `1 - m` on the
extra bin, where m is the target image mass. For the forward KL this is

    m * KL(gaze || attention / M) + KL(Bernoulli(m) || Bernoulli(M)),   M = attention mass on the patches,

so the patch distribution is still pulled towards the gaze, and M towards m.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from gazereg.losses import Divergence, compute_dtype, gaze_kl, gaze_loss
from gazereg.runtime.errors import UsageError


def check_target_mass(target_mass: float) -> float:
    """The target image mass must be a number in (0, 1]."""
    if not (isinstance(target_mass, int | float) and math.isfinite(target_mass) and 0 < target_mass <= 1):
        raise UsageError(f"gaze target mass must be in (0, 1], got {target_mass!r}")
    return float(target_mass)


def mass_bins(gaze: Tensor, attention: Tensor, target_mass: float) -> tuple[Tensor, Tensor]:
    """Target and attention over N + 1 bins.

    gaze: (B, N) non-negative (renormalised here); attention: (B, N) the attention to each patch, NOT
    renormalised (row sums = the image mass M in [0, 1]). Returns (target (B, N + 1), attention (B, N + 1)):
    [m * gaze, 1 - m] and [attention, 1 - M] (clamped at 0), in float32 (float64 kept)."""
    m = check_target_mass(target_mass)
    if gaze.shape != attention.shape:
        raise ValueError(
            f"gaze {tuple(gaze.shape)} and attention {tuple(attention.shape)} must have the same shape"
        )
    dtype = compute_dtype(attention.dtype)
    a = attention.to(dtype).clamp_min(0)
    g = gaze.to(device=a.device, dtype=dtype).clamp_min(0)
    g = g / g.sum(-1, keepdim=True).clamp_min(1e-12)
    rest = (1 - a.sum(-1, keepdim=True)).clamp_min(0)
    target = torch.cat([m * g, torch.full_like(rest, 1 - m)], dim=-1)
    return target, torch.cat([a, rest], dim=-1)


def gaze_mass_kl(
    gaze: Tensor, attention: Tensor, target_mass: float, kind: Divergence = "forward", eps: float = 1e-8
) -> Tensor:
    """(B,) divergence between [m * gaze, 1 - m] and [attention, 1 - M] over N + 1 bins (see `mass_bins`)."""
    target, att = mass_bins(gaze, attention, target_mass)
    return gaze_kl(target, att, kind=kind, eps=eps)


def gaze_mass_loss(
    gaze: Tensor,
    attention: Tensor,
    target_mass: float,
    valid: Tensor | None = None,
    kind: Divergence = "forward",
    eps: float = 1e-8,
) -> tuple[Tensor, dict[str, float]]:
    """Mean over valid samples of `gaze_mass_kl`; info as `gazereg.losses.gaze_loss` gives it.

    gaze, attention: (B, N) (attention not renormalised); valid: optional (B,) bool."""
    target, att = mass_bins(gaze, attention, target_mass)
    return gaze_loss(target, att, valid, kind=kind, eps=eps)
