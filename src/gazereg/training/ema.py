"""Exponential moving average of a model's parameters (the weights saved for evaluation when enabled)."""

from __future__ import annotations

import copy

import torch
from torch import nn


class EMA:
    """shadow = decay_t * shadow + (1 - decay_t) * params after every optimizer step, with the usual warm-up
    decay_t = min(decay, (1 + n) / (10 + n)); buffers (normalisation stats) are copied."""

    def __init__(self, model: nn.Module, decay: float):
        if not 0 < decay < 1:
            raise ValueError(f"EMA decay must be in (0, 1), got {decay}")
        self.decay = decay
        self.model = copy.deepcopy(model).eval()
        for p in self.model.parameters():
            p.requires_grad_(False)
        self.updates = 0

    @torch.no_grad()
    def update(self, model: nn.Module) -> None:
        d = min(self.decay, (1 + self.updates) / (10 + self.updates))
        for e, p in zip(self.model.parameters(), model.parameters()):
            e.lerp_(p.detach(), 1 - d)
        for e, b in zip(self.model.buffers(), model.buffers()):
            e.copy_(b)
        self.updates += 1

    def state_dict(self) -> dict[str, torch.Tensor]:
        return self.model.state_dict()

    def load_state_dict(self, sd: dict[str, torch.Tensor], updates: int) -> None:
        self.model.load_state_dict(sd)
        self.updates = updates
