"""The learning-rate schedule, the optimiser's parameter groups and the per-step random generator: the pieces
every training loop here (policies and GLC) shares."""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import nn


def lr_lambda(step: int, total: int, warmup: int, min_frac: float) -> float:
    if warmup > 0 and step < warmup:
        return (step + 1) / warmup
    t = min(1.0, max(0.0, (step - warmup) / max(1, total - warmup)))
    return min_frac + (1 - min_frac) * 0.5 * (1 + math.cos(math.pi * t))


def param_groups(model: nn.Module, weight_decay: float) -> list[dict[str, Any]]:
    """Weight decay on matrices and conv kernels; none on biases, norms, embeddings and position tables."""
    decay, no_decay = [], []
    for name, p in model.named_parameters():
        if not p.requires_grad:
            continue
        skip = p.ndim < 2 or "pos" in name or "embed" in name
        (no_decay if skip else decay).append(p)
    return [{"params": decay, "weight_decay": weight_decay}, {"params": no_decay, "weight_decay": 0.0}]


def step_generator(seed: int, step: int, rank: int, device: torch.device) -> torch.Generator:
    """The generator for every random draw of one training step (augmentation, flow noise)."""
    g = torch.Generator(device=device)
    g.manual_seed((seed * 1_000_003 + step) * 1009 + rank)
    return g
