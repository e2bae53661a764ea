"""Helpers for the GLC tests: the README's synthetic weights (imported by the test modules)."""

from __future__ import annotations

import zlib

import numpy as np
import torch


def synthetic_tensor(key: str, shape: tuple[int, ...]) -> torch.Tensor:
    """The README's deterministic stand-in for the state-dict entry `key` (floating-point entries)."""
    rng = np.random.default_rng(zlib.crc32(key.encode()))
    if key.endswith("running_var"):
        a = 0.5 + rng.random(shape)
    elif key.endswith("running_mean") or (len(shape) <= 1 and not key.endswith("weight")):
        a = 0.05 * rng.standard_normal(shape)
    elif len(shape) == 1 and key.endswith("weight"):
        a = 1.0 + 0.1 * rng.standard_normal(shape)
    else:
        a = rng.standard_normal(shape) / np.sqrt(np.prod(shape[1:]))
    return torch.from_numpy(np.asarray(a, dtype=np.float32))


def synthetic_state_dict(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {
        k: synthetic_tensor(k, tuple(v.shape)) if v.is_floating_point() else v.clone()
        for k, v in model.state_dict().items()
    }
