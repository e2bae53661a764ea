"""What GLC training reads: clip / gaze items, their batches in a reproducible order, and a synthetic set.

An item is `(clip (3, T, H, W), gaze (T, 2), valid (T,))`: a clip of uint8 in [0, 255] or floats in [0, 1],
its gaze points normalised `(u right, v down)` in [0, 1], and False where the gaze is missing. Items may
also be dicts with the keys `clips`, `gaze` and optionally `valid`; `valid` defaults to all True.

With a map-style dataset the batch of step `s` holds the items `StepBatchSampler` (the policy trainer's
sampler) picks for `(seed, s)`, so a resumed run reads exactly the batches an uninterrupted one would.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

import torch
from torch.utils.data import Dataset

from gazereg.data.dataset import StepBatchSampler

Batch = tuple[torch.Tensor, torch.Tensor, torch.Tensor]
"""`(clips (B, 3, T, H, W), gaze (B, T, 2), valid (B, T))`"""


class ClipGazeDataset(Dataset):
    """Map-style dataset over in-memory tensors: item `i` -> `(clip (3,T,H,W), gaze (T,2), valid (T,))`."""

    def __init__(self, clips: torch.Tensor, gaze: torch.Tensor, valid: torch.Tensor | None = None) -> None:
        if clips.ndim != 5 or gaze.shape[:2] != (clips.shape[0], clips.shape[2]) or gaze.shape[-1] != 2:
            raise ValueError(f"clips (N,3,T,H,W) and gaze (N,T,2) expected, got {clips.shape}, {gaze.shape}")
        self.clips, self.gaze = clips, gaze.float()
        self.valid = torch.ones(gaze.shape[:2], dtype=torch.bool) if valid is None else valid.bool()

    def __len__(self) -> int:
        return self.clips.shape[0]

    def __getitem__(self, i: int) -> Batch:
        return self.clips[i], self.gaze[i], self.valid[i]


def moving_dot_clips(
    n: int, frames: int = 8, size: int = 96, seed: int = 0, radius: float = 0.06
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Synthetic egocentric-gaze stand-in: a bright dot drifting over a noisy dark background.

    Returns uint8 clips `(n, 3, frames, size, size)`, gaze `(n, frames, 2)` at the dot centre
    (normalised u, v), and `valid (n, frames)` all True. `radius` is in normalised image units.
    """
    g = torch.Generator().manual_seed(seed)
    start = 0.2 + 0.6 * torch.rand(n, 1, 2, generator=g)
    vel = (torch.rand(n, 1, 2, generator=g) - 0.5) * 0.08
    t = torch.arange(frames, dtype=torch.float32)[None, :, None]
    gaze = (start + vel * t).clamp(0.05, 0.95)
    coords = (torch.arange(size, dtype=torch.float32) + 0.5) / size
    du = coords[None, None, None, :] - gaze[..., 0, None, None]
    dv = coords[None, None, :, None] - gaze[..., 1, None, None]
    dot = torch.exp(-(du**2 + dv**2) / (2 * radius**2))  # (n, T, size, size)
    noise = 0.15 * torch.rand(n, 3, frames, size, size, generator=g)
    colour = 0.6 + 0.4 * torch.rand(n, 3, 1, 1, 1, generator=g)
    clips = (noise + colour * dot[:, None]).clamp(0, 1)
    return (clips * 255).round().to(torch.uint8), gaze, torch.ones(n, frames, dtype=torch.bool)


def as_clip_dataset(data: Any) -> Dataset | None:
    """A map-style dataset for `(clips, gaze[, valid])` tensors, a dict of them, or a dataset (returned as is);
    None for anything else (an iterable of batches)."""
    if (
        isinstance(data, tuple | list)
        and len(data) in (2, 3)
        and all(isinstance(x, torch.Tensor) for x in data)
    ):
        return ClipGazeDataset(*data)
    if isinstance(data, dict) and "clips" in data:
        return ClipGazeDataset(data["clips"], data["gaze"], data.get("valid"))
    if hasattr(data, "__getitem__") and hasattr(data, "__len__"):
        return data
    return None


def unpack_item(item: Any) -> Batch:
    """`(clip, gaze, valid)` of a tuple or dict item (or batch); `valid` all True when absent."""
    if isinstance(item, dict):
        clip, gaze, valid = item["clips"], item["gaze"], item.get("valid")
    else:
        clip, gaze, *rest = item
        valid = rest[0] if rest else None
    if valid is None:
        valid = torch.ones(gaze.shape[:-1], dtype=torch.bool)
    return clip, gaze, valid


def stack_items(ds: Dataset, indices: Iterable[int]) -> Batch:
    """The items `indices` of `ds`, stacked into one batch."""
    items = [unpack_item(ds[i]) for i in indices]
    return tuple(torch.stack([it[k] for it in items]) for k in range(3))  # type: ignore[return-value]


def step_batches(
    ds: Dataset, batch_size: int, seed: int, start_step: int, total_steps: int
) -> Iterator[Batch]:
    """Batches of steps `start_step .. total_steps - 1`; step `s` depends only on `(seed, s)`."""
    sampler = StepBatchSampler(len(ds), batch_size, seed, total_steps, start_step)
    for indices in sampler:
        yield stack_items(ds, indices)


def training_batches(
    data: Any, batch_size: int, seed: int, start_step: int, total_steps: int
) -> Iterator[Batch]:
    """Reproducible batches of a dataset / tensors (`step_batches`), or the batches of an iterable as they come."""
    ds = as_clip_dataset(data)
    if ds is not None:
        return step_batches(ds, batch_size, seed, start_step, total_steps)
    return (unpack_item(item) for item in data)
