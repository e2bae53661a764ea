"""Input processing of the reference VLA: an offline tokenizer, state/action normalisation, image geometry and
augmentation.

Nothing here downloads anything. The tokenizer is either a word vocabulary built from the training
instructions (stored in the checkpoint as `tokenizer.json`) or UTF-8 bytes.

Image geometry: stored frames (uint8, (H, W, 3), upright) are flipped by the configured orientation and
stretched to the policy's input size; `PatchGeometry` (from `VLAPolicy.geometry`) describes the same map
for gaze, so frames and gaze can never disagree.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from gazereg.runtime.io import atomic_write_text

PAD, UNK = "<pad>", "<unk>"
_WORD = re.compile(r"[a-z0-9]+")  # lower-cased words and numbers; punctuation is dropped


class Tokenizer:
    """Instruction -> token ids (max_len,) + mask. Id 0 is padding, 1 unknown."""

    def __init__(self, kind: str = "words", vocab: Sequence[str] | None = None, max_len: int = 16):
        if kind not in ("words", "bytes"):
            raise ValueError(f"unknown tokenizer kind {kind!r}; use 'words' or 'bytes'")
        self.kind, self.max_len = kind, int(max_len)
        if kind == "bytes":
            self.vocab = [PAD, UNK] + [f"<0x{i:02x}>" for i in range(256)]
        else:
            vocab = list(vocab or [])
            if vocab[:2] != [PAD, UNK]:
                vocab = [PAD, UNK, *[w for w in vocab if w not in (PAD, UNK)]]
            self.vocab = vocab
        self._index = {w: i for i, w in enumerate(self.vocab)}

    @classmethod
    def build(cls, instructions: Iterable[str], kind: str = "words", max_len: int = 16) -> Tokenizer:
        """A word vocabulary from a data set's instructions (sorted, so the same data give the same ids)."""
        if kind == "bytes":
            return cls("bytes", max_len=max_len)
        words = sorted({w for text in instructions for w in cls.split(text)})
        return cls("words", words, max_len)

    @staticmethod
    def split(text: str) -> list[str]:
        return _WORD.findall(text.lower())

    @property
    def vocab_size(self) -> int:
        return len(self.vocab)

    def ids(self, text: str) -> list[int]:
        if self.kind == "bytes":
            out = [b + 2 for b in text.encode("utf-8")]
        else:
            out = [self._index.get(w, 1) for w in self.split(text)]
        return out[: self.max_len]

    def __call__(self, texts: str | Sequence[str]) -> tuple[Tensor, Tensor]:
        """Returns ids (B, max_len) long and mask (B, max_len) bool (True = a real token)."""
        if isinstance(texts, str):
            texts = [texts]
        ids = torch.zeros(len(texts), self.max_len, dtype=torch.long)
        for i, t in enumerate(texts):
            row = self.ids(t)
            ids[i, : len(row)] = torch.tensor(row, dtype=torch.long)
        return ids, ids != 0

    def unknown_words(self, text: str) -> list[str]:
        return [] if self.kind == "bytes" else [w for w in self.split(text) if w not in self._index]

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "max_len": self.max_len,
            "vocab": self.vocab if self.kind == "words" else None,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Tokenizer:
        return cls(d["kind"], d.get("vocab"), d["max_len"])

    def save(self, path: str | Path) -> None:
        atomic_write_text(path, json.dumps(self.to_dict(), indent=1) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> Tokenizer:
        return cls.from_dict(json.loads(Path(path).read_text()))


def to_input_images(frames: Tensor, image_hw: tuple[int, int], orientation: str = "none") -> Tensor:
    """Stored frames -> the policy's input images.

    frames: uint8 (B, H, W, 3) (channels last, as stored) or (B, 3, H, W); float inputs are taken as [0, 255].
    Returns float32 (B, 3, H_in, W_in) in [-1, 1], oriented and stretched to image_hw (bilinear, antialiased).
    """
    if frames.ndim != 4:
        raise ValueError(f"frames must be (B, H, W, 3) or (B, 3, H, W), got {tuple(frames.shape)}")
    x = frames.permute(0, 3, 1, 2) if frames.shape[-1] == 3 and frames.shape[1] != 3 else frames
    if x.shape[1] != 3:
        raise ValueError(f"frames must have 3 colour channels, got shape {tuple(frames.shape)}")
    x = x.float()
    if orientation == "rot180":
        x = x.flip(-1, -2)
    elif orientation == "hflip":
        x = x.flip(-1)
    elif orientation == "vflip":
        x = x.flip(-2)
    elif orientation != "none":
        raise ValueError(f"unknown orientation {orientation!r}")
    if tuple(x.shape[-2:]) != tuple(image_hw):
        x = F.interpolate(x, size=tuple(image_hw), mode="bilinear", antialias=True, align_corners=False)
    return x * (2.0 / 255.0) - 1.0


def random_shift(images: Tensor, pad: int, generator: torch.Generator) -> Tensor:
    """DrQ-style augmentation: replicate-pad by `pad` px and crop back at a random integer offset per image.

    images: (B, C, H, W); the offsets come from `generator` only (no global RNG), so a run is reproducible
    and resumable. Gaze targets are not shifted: the shift (<= pad px) is kept below half a patch."""
    if pad <= 0:
        return images
    B, _, H, W = images.shape
    padded = F.pad(images, (pad, pad, pad, pad), mode="replicate")
    off = torch.randint(0, 2 * pad + 1, (B, 2), generator=generator, device=generator.device).tolist()
    return torch.stack([padded[i, :, r : r + H, c : c + W] for i, (r, c) in enumerate(off)])


class Normalizer(nn.Module):
    """Mean/std of state and action, kept with the policy (saved in model.safetensors as buffers)."""

    def __init__(self, state_dim: int, action_dim: int, eps: float):
        super().__init__()
        self.eps = eps
        self.register_buffer("state_mean", torch.zeros(state_dim))
        self.register_buffer("state_std", torch.ones(state_dim))
        self.register_buffer("action_mean", torch.zeros(action_dim))
        self.register_buffer("action_std", torch.ones(action_dim))

    @torch.no_grad()
    def set_stats(self, state_mean: Any, state_std: Any, action_mean: Any, action_std: Any) -> None:
        for name, v in (
            ("state_mean", state_mean),
            ("state_std", state_std),
            ("action_mean", action_mean),
            ("action_std", action_std),
        ):
            t = torch.as_tensor(np.asarray(v, dtype=np.float32))
            buf = getattr(self, name)
            if t.shape != buf.shape or not torch.isfinite(t).all():
                raise ValueError(
                    f"normalisation {name} must be a finite {tuple(buf.shape)} vector, got {tuple(t.shape)}"
                )
            if name.endswith("std"):
                t = t.clamp_min(self.eps)
            buf.copy_(t)

    def state(self, x: Tensor) -> Tensor:
        return (x - self.state_mean) / self.state_std

    def action(self, x: Tensor) -> Tensor:
        return (x - self.action_mean) / self.action_std

    def unaction(self, x: Tensor) -> Tensor:
        return x * self.action_std + self.action_mean

    def stats(self) -> dict[str, list[float]]:
        return {k: v.tolist() for k, v in self.state_dict().items()}
