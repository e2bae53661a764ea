"""A second policy, defined outside the library, that implements `gazereg.policies.base.Policy`: the proof
that training and evaluation need nothing policy-specific.

ToyPolicy: a strided conv turns each camera's input image into an h x w grid of patch tokens; K learned
action queries (plus an embedding of the instruction) attend, in one single-head attention layer (layer 0,
tapped for the gaze probe), over [patch tokens of every camera | one state token]; a linear map of each
query's output gives the K normalised actions. L1 loss on normalised actions.

Shapes: B batch, K chunk, A action dim, S state dim, D width, N patches per camera, C cameras.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from gazereg.attention.probe import ProbeSpec, tap
from gazereg.data.dataset import StoreInfo
from gazereg.patches import PatchGeometry
from gazereg.policies import Policy, PolicyConfig


@dataclass(frozen=True)
class ToyConfig(PolicyConfig):
    type: ClassVar[str] = "toy"

    image_hw: tuple[int, int] = (24, 24)
    patch_size: int = 8
    dim: int = 16
    chunk: int = 2
    n_instructions: int = 0
    """filled from the data: the tokenizer's number of known instructions"""

    @property
    def n_patches(self) -> int:
        return (self.image_hw[0] // self.patch_size) * (self.image_hw[1] // self.patch_size)

    @property
    def resolved(self) -> bool:
        return super().resolved and self.n_instructions > 0


class InstructionTokenizer:
    """Each training instruction is one token: ids (B, 1) long in 1..n (0: unknown), mask (B, 1) all True."""

    def __init__(self, instructions: Sequence[str]):
        self.instructions = sorted(set(instructions))
        self._index = {text: i + 1 for i, text in enumerate(self.instructions)}

    def __call__(self, texts: str | Sequence[str]) -> tuple[Tensor, Tensor]:
        texts = [texts] if isinstance(texts, str) else list(texts)
        ids = torch.tensor([[self._index.get(t, 0)] for t in texts], dtype=torch.long)
        return ids, torch.ones_like(ids, dtype=torch.bool)

    def to_dict(self) -> dict[str, Any]:
        return {"instructions": self.instructions}


class ToyPolicy(Policy):
    config_class = ToyConfig
    config: ToyConfig

    def __init__(self, config: ToyConfig, tokenizer: InstructionTokenizer):
        super().__init__(config, tokenizer)
        D, K, C = config.dim, config.chunk, len(config.cameras)
        self.patchify = nn.Conv2d(3, D, config.patch_size, stride=config.patch_size)
        self.pos = nn.Parameter(torch.randn(C * config.n_patches, D) * 0.02)
        self.state_in = nn.Linear(config.state_dim, D)
        self.instruction = nn.Embedding(config.n_instructions + 1, D)
        self.queries = nn.Parameter(torch.randn(K, D) * 0.02)
        self.q, self.k, self.v = nn.Linear(D, D), nn.Linear(D, D), nn.Linear(D, D)
        self.out = nn.Linear(D, config.action_dim)
        for name, dim in (("state", config.state_dim), ("action", config.action_dim)):
            self.register_buffer(f"{name}_mean", torch.zeros(dim))
            self.register_buffer(f"{name}_std", torch.ones(dim))

    # ----- built from data -----------------------------------------------------------------------------
    @classmethod
    def from_data(cls, config: ToyConfig, data: StoreInfo) -> ToyPolicy:  # type: ignore[override]
        tok = InstructionTokenizer(data.instructions)
        return cls(dataclasses.replace(config.resolve(data), n_instructions=len(tok.instructions)), tok)

    @classmethod
    def load_tokenizer(cls, path: Path) -> InstructionTokenizer:
        return InstructionTokenizer(json.loads(path.read_text())["instructions"])

    @torch.no_grad()
    def set_normalization(self, state_mean: Any, state_std: Any, action_mean: Any, action_std: Any) -> None:
        for name, v in zip(
            ("state_mean", "state_std", "action_mean", "action_std"),
            (state_mean, state_std, action_mean, action_std),
        ):
            t = torch.as_tensor(np.asarray(v, dtype=np.float32))
            getattr(self, name).copy_(t.clamp_min(1e-3) if name.endswith("std") else t)

    # ----- gaze ----------------------------------------------------------------------------------------
    def geometry(self, camera: str) -> PatchGeometry:
        c = self.config
        src = c.camera_hw[c.cameras.index(camera)]
        return PatchGeometry(input_hw=c.image_hw, patch_size=c.patch_size, src_hw=src, resize="stretch")

    def resolve_layers(self, layers: Sequence[int] | None) -> tuple[int, ...]:
        out = tuple(sorted({0 if lay == -1 else lay for lay in (layers if layers is not None else (0,))}))
        if out != (0,):
            raise ValueError(f"attention layers {list(layers or ())} out of range for a 1-layer policy")
        return out

    def gaze_probe_spec(self, camera: str, layers: Sequence[int] | None = None) -> ProbeSpec:
        i, N = self.config.cameras.index(camera), self.config.n_patches
        return ProbeSpec(
            queries=slice(0, self.config.chunk),
            keys=slice(i * N, (i + 1) * N),
            layers=self.resolve_layers(layers),
        )

    # ----- forward -------------------------------------------------------------------------------------
    def tokens(self, batch: Mapping[str, Tensor], shift: int, generator: torch.Generator | None) -> Tensor:
        """(B, C * N + 1, D): every camera's patch tokens, then the state token."""
        c, dev = self.config, self.device
        patches = []
        for cam in c.cameras:
            x = batch[f"image.{cam}"].to(dev).permute(0, 3, 1, 2).float() * (2 / 255) - 1
            x = F.interpolate(x, size=c.image_hw, mode="bilinear", align_corners=False)
            if shift > 0:
                oy, ox = torch.randint(0, 2 * shift + 1, (2,), generator=generator).tolist()
                x = F.pad(x, (shift,) * 4, mode="replicate")[
                    ..., oy : oy + c.image_hw[0], ox : ox + c.image_hw[1]
                ]
            patches.append(self.patchify(x).flatten(2).transpose(1, 2))
        state = (batch["state"].to(dev).float() - self.state_mean) / self.state_std
        return torch.cat([torch.cat(patches, 1) + self.pos, self.state_in(state)[:, None]], 1)

    def predict(
        self, batch: Mapping[str, Tensor], shift: int = 0, generator: torch.Generator | None = None
    ) -> Tensor:
        """(B, K, A) normalised actions."""
        kv = self.tokens(batch, shift, generator)
        query = self.queries + self.instruction(batch["text_ids"].to(self.device))  # (B, K, D)
        q, k = self.q(query)[:, None], self.k(kv)[:, None]  # (B, 1, K, D), (B, 1, T, D)
        tap(0, q, k)
        probs = torch.softmax(q @ k.transpose(-1, -2) / math.sqrt(q.shape[-1]), -1)
        return self.out((probs @ self.v(kv)[:, None])[:, 0])

    def forward(
        self, batch: Mapping[str, Tensor], generator: torch.Generator | None = None, shift: int = 0
    ) -> tuple[Tensor, dict[str, Any]]:
        target = (batch["action"].to(self.device).float() - self.action_mean) / self.action_std
        keep = (~batch["action_pad"].to(self.device)).float()[..., None]
        err = (self.predict(batch, shift, generator) - target).abs()
        loss = (err * keep).sum() / (keep.sum() * err.shape[-1]).clamp_min(1.0)
        return loss, {"loss/action": float(loss.detach())}

    @torch.no_grad()
    def select_action(
        self,
        observation: Mapping[str, Any],
        instruction: str | Sequence[str],
        generator: torch.Generator | None = None,
    ) -> np.ndarray:
        images = observation.get("images", observation)
        state = torch.as_tensor(np.asarray(observation["state"], dtype=np.float32))
        batched = state.ndim == 2
        add = (lambda t: t) if batched else (lambda t: t[None])
        batch = {f"image.{cam}": add(torch.as_tensor(np.asarray(images[cam]))) for cam in self.config.cameras}
        batch["state"] = add(state)
        texts = [instruction] * batch["state"].shape[0] if isinstance(instruction, str) else list(instruction)
        batch["text_ids"], _ = self.tokenizer(texts)
        action = self.predict(batch)[:, 0] * self.action_std + self.action_mean
        action = action if batched else action[0]
        return action.cpu().numpy().astype(np.float32)
