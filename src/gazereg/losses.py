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


def check_eps(eps: float) -> float:
    """eps must be a positive, finite float: the floor under the logarithm (0 would give log 0 = -inf)."""
    if not (isinstance(eps, int | float) and math.isfinite(eps) and eps > 0):
        raise ValueError(f"loss eps must be a positive finite number, got {eps!r}")
    return float(eps)


def check_grids(n: int, gaze_grid: tuple[int, int] | None, attention_grid: tuple[int, int] | None) -> None:
    """Distributions with the same patch count on differently shaped grids (8x8 vs 4x16) are not comparable:
    raise when the given grids differ or do not hold n patches."""
    for name, grid in (("gaze", gaze_grid), ("attention", attention_grid)):
        if grid is not None and grid[0] * grid[1] != n:
            raise ValueError(f"{name} grid {tuple(grid)} does not hold the distributions' {n} patches")
    if gaze_grid is not None and attention_grid is not None and tuple(gaze_grid) != tuple(attention_grid):
        raise ValueError(
            f"gaze grid {tuple(gaze_grid)} and attention grid {tuple(attention_grid)} differ: the gaze targets "
            "were made for another patch geometry than the policy's"
        )


def compute_dtype(dtype: torch.dtype) -> torch.dtype:
    """float32 for half-precision inputs (fp16/bf16 underflow the eps floor and overflow the log ratio),
    float64 kept as it is."""
    return torch.float64 if dtype == torch.float64 else torch.float32


def gaze_kl(gaze: Tensor, attention: Tensor, kind: Divergence = "forward", eps: float = 1e-8) -> Tensor:
    """Per-sample divergence between gaze (B, N) and attention (B, N) distributions -> (B,).

    Inputs are renormalised over N (after clamping at 0) so small numerical drift cannot make the result
    negative; values stay finite when either input has zeros. Computed in float32 (float64 for float64
    attention) whatever the input dtype, so fp16/bf16 attention under autocast gives a finite loss and
    finite gradients; the result has that compute dtype."""
    if gaze.shape != attention.shape:
        raise ValueError(
            f"gaze {tuple(gaze.shape)} and attention {tuple(attention.shape)} must have the same shape"
        )
    eps = check_eps(eps)
    dtype = compute_dtype(attention.dtype)
    g = gaze.detach().to(dtype).clamp_min(0)
    a = attention.to(dtype).clamp_min(0)
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
    gaze_grid: tuple[int, int] | None = None,
    attention_grid: tuple[int, int] | None = None,
) -> tuple[Tensor, dict[str, float]]:
    """Mean divergence over valid samples.

    Args:
        gaze: (B, N) target distributions (no gradient).
        attention: (B, N) the policy's attention distributions (differentiable).
        valid: (B,) bool; invalid samples (no usable gaze) are excluded from the mean.
        gaze_grid, attention_grid: (rows, cols) of the patch grids the two are row-major over; when given they
            must hold N patches and agree (see `check_grids`).
    Returns:
        loss: scalar; exactly 0 (still attached to the graph) when no sample is valid.
        info: {"gaze/valid_frac", "gaze/no_valid"} for logging.
    """
    check_grids(gaze.shape[-1], gaze_grid, attention_grid)
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
        if not (math.isfinite(self.weight) and self.weight >= 0):
            raise ValueError(f"gaze weight must be a finite number >= 0, got {self.weight}")
        if self.warmup_steps < 0 or self.total_steps < 1:
            raise ValueError(
                f"gaze schedule needs warmup_steps >= 0 and total_steps >= 1, got {self.warmup_steps}, "
                f"{self.total_steps}"
            )
        if not 0 <= self.final_frac <= 1:
            raise ValueError(f"gaze schedule final_frac must be in [0, 1], got {self.final_frac}")
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


def across_processes(kl: Tensor, valid: Tensor) -> Tensor:
    """`kl` () (the mean over this process's valid frames; `valid` (B,) bool) rescaled to this process's share of
    the mean over every process's valid frames: kl * n_local * world / n_global, so that averaging it over the
    processes (DDP's gradient average, lerobot-train's log) gives sum over all valid frames / n_global. Returned
    unchanged outside torch.distributed, with one process, or when no process has a valid frame."""
    if not (torch.distributed.is_available() and torch.distributed.is_initialized()):
        return kl
    world = torch.distributed.get_world_size()
    if world == 1:
        return kl
    n_local = valid.detach().to(device=kl.device, dtype=torch.float64).sum()
    n_global = n_local.clone().reshape(1)
    torch.distributed.all_reduce(n_global)  # a sum over the processes
    total = float(n_global.item())
    if total == 0:
        return kl
    return kl * (float(n_local) * world / total)
