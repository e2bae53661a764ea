"""The gaze regularizer: a divergence between the gaze distribution and the policy's attention.

    L = L_action + weight(step) * mean_{valid b} D(gaze_b, attention_b)

with D = KL(gaze || attention) by default (attention is pushed to cover the gaze mass), KL(attention || gaze)
or Jensen-Shannon as options. Gaze is the target: no gradient flows into it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor

Divergence = Literal["forward", "reverse", "js"]


def _kl(p: Tensor, q: Tensor, eps: float) -> Tensor:
    """Row-wise KL(p || q) with 0 log 0 = 0; both (..., N) non-negative summing to 1."""
    logp = torch.log(p.clamp_min(eps))
    logq = torch.log(q.clamp_min(eps))
    return torch.where(p > 0, p * (logp - logq), torch.zeros_like(p)).sum(-1)


def gaze_kl(gaze: Tensor, attention: Tensor, kind: Divergence = "forward", eps: float = 1e-8) -> Tensor:
    """Per-sample divergence between gaze (B, N) and attention (B, N) distributions -> (B,).

    Inputs are renormalised over N (after clamping at 0) so small numerical drift cannot make the result
    negative; values stay finite when either input has zeros."""
    if gaze.shape != attention.shape:
        raise ValueError(
            f"gaze {tuple(gaze.shape)} and attention {tuple(attention.shape)} must have the same shape"
        )
    g = gaze.detach().to(attention.dtype).clamp_min(0)
    a = attention.clamp_min(0)
    g = g / g.sum(-1, keepdim=True).clamp_min(eps)
    a = a / a.sum(-1, keepdim=True).clamp_min(eps)
    if kind == "forward":
        d = _kl(g, a, eps)
    elif kind == "reverse":
        d = _kl(a, g, eps)
    elif kind == "js":
        m = 0.5 * (g + a)
        d = 0.5 * _kl(g, m, eps) + 0.5 * _kl(a, m, eps)
    else:
        raise ValueError(f"unknown divergence {kind!r}; use forward, reverse or js")
    return d.clamp_min(0)


def gaze_loss(
    gaze: Tensor,
    attention: Tensor,
    valid: Tensor | None = None,
    kind: Divergence = "forward",
    eps: float = 1e-8,
) -> tuple[Tensor, dict[str, float]]:
    """Mean divergence over valid samples.

    Args:
        gaze: (B, N) target distributions (no gradient).
        attention: (B, N) the policy's attention distributions (differentiable).
        valid: (B,) bool; invalid samples (no usable gaze) are excluded from the mean.
    Returns:
        loss: scalar; exactly 0 (still attached to the graph) when no sample is valid.
        info: {"gaze/valid_frac", "gaze/no_valid"} for logging.
    """
    if not torch.isfinite(gaze).all():
        raise ValueError("gaze distribution contains NaN or inf")
    if not torch.isfinite(attention).all():
        raise ValueError("attention distribution contains NaN or inf (check the probe's layers and masks)")
    B = gaze.shape[0]
    valid = torch.ones(B, dtype=torch.bool, device=gaze.device) if valid is None else valid.to(torch.bool)
    if valid.shape != (B,):
        raise ValueError(f"valid must be ({B},), got {tuple(valid.shape)}")
    per_sample = gaze_kl(gaze, attention, kind=kind, eps=eps)
    n = int(valid.sum())
    info = {"gaze/valid_frac": n / max(B, 1), "gaze/no_valid": float(n == 0)}
    if n == 0:
        return (attention * 0).sum(), info
    loss = (per_sample * valid).sum() / n
    return loss, info


@dataclass(frozen=True)
class WeightSchedule:
    """The regularizer weight over training steps.

    constant: weight; linear_warmup: 0 -> weight over warmup_steps, then constant;
    cosine: weight decays to final_frac * weight over total_steps with a half cosine (after any warm-up)."""

    weight: float = 0.1
    kind: Literal["constant", "linear_warmup", "cosine"] = "constant"
    warmup_steps: int = 0
    total_steps: int = 1
    final_frac: float = 0.0

    def __post_init__(self) -> None:
        if self.weight < 0:
            raise ValueError(f"gaze weight must be >= 0, got {self.weight}")
        if self.kind not in ("constant", "linear_warmup", "cosine"):
            raise ValueError(f"unknown schedule {self.kind!r}")

    def __call__(self, step: int) -> float:
        w = self.weight
        if self.warmup_steps > 0 and step < self.warmup_steps and self.kind != "constant":
            return w * (step + 1) / self.warmup_steps
        if self.kind == "cosine":
            span = max(1, self.total_steps - self.warmup_steps)
            t = min(1.0, max(0.0, (step - self.warmup_steps) / span))
            return w * (self.final_frac + (1 - self.final_frac) * 0.5 * (1 + math.cos(math.pi * t)))
        return w


@dataclass(frozen=True)
class GazeLossConfig:
    """Everything about the gaze term a training config needs."""

    enabled: bool = True
    divergence: Divergence = "forward"
    schedule: WeightSchedule = WeightSchedule()
    eps: float = 1e-8
