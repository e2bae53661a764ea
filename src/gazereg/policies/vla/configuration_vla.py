"""Configuration of the reference VLA policy (frozen dataclasses, the policy sizes `tiny` and `large`).

A config has two kinds of fields: architecture choices (widths, depth, image and patch size, head) set by a
preset, and data-dependent fields (cameras and their stored frame sizes, state/action dimensions from
`PolicyConfig`, the tokenizer's vocabulary size) that `VLAPolicy.from_data` fills in from the training data
set. A resolved config fully determines the parameter shapes; it is stored as `config.json` beside
`model.safetensors`. Registered as policy type "vla".
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Literal

from gazereg.patches import Orientation
from gazereg.policies.base import PolicyConfig

Head = Literal["l1", "flow"]
AttentionImpl = Literal["math", "sdpa"]


@dataclass(frozen=True)
class VLAConfig(PolicyConfig):
    type: ClassVar[str] = "vla"

    # ----- vision (cameras and camera_hw: PolicyConfig) ----------------------------------------------------
    image_hw: tuple[int, int] = (96, 96)
    """policy input size (H, W) every camera is resized (stretched) to"""
    patch_size: int = 12
    """pixels per patch token side: 96 px / 12 = an 8 x 8 token grid"""
    stem_stride: int = 4
    """the conv stem: a stride-`stem_stride` patchify conv, a 3x3 conv, then a stride-(patch/stem) conv"""
    stem_channels: int = 32
    orientation: Orientation = "none"
    """flip applied to stored frames before the policy sees them (stored frames are upright already)"""
    # ----- language -------------------------------------------------------------------------------------
    tokenizer: Literal["words", "bytes"] = "words"
    """words: a vocabulary built from the training instructions; bytes: UTF-8 bytes (any text)"""
    max_text_len: int = 12
    vocab_size: int = 0
    """filled from the tokenizer"""
    # ----- transformer ----------------------------------------------------------------------------------
    dim: int = 128
    depth: int = 4
    heads: int = 4
    mlp_ratio: float = 2.0
    dropout: float = 0.0
    attention: AttentionImpl = "math"
    """math: q k^T, then the mask and softmax in float32 (on a 2-core AVX-512 CPU at 81 tokens as fast as
    SDPA in float32 and about 4x faster in bf16: benchmarks/bench_train.py); sdpa: the fused
    `scaled_dot_product_attention` kernels (long sequences, GPUs). Same function, same weights."""
    # ----- actions (state_dim and action_dim: PolicyConfig) ---------------------------------------------
    chunk: int = 4
    """K: actions predicted per forward pass (the action query tokens)"""
    head: Head = "l1"
    """l1: regression of normalised actions; flow: flow matching (pi0-style), sampled with Euler steps"""
    flow_steps: int = 10
    # ----- inference ------------------------------------------------------------------------------------
    n_action_steps: int = 1
    """receding horizon: execute the first n actions of a chunk, then predict a new chunk"""
    temporal_ensemble: float | None = None
    """if set, predict every step and average all chunks' predictions for the current step with weights
    exp(-coef * age_index) (ACT's temporal ensembling; 0.0 = plain mean); overrides n_action_steps"""
    norm_eps: float = 1e-3
    """floor on the standard deviations used to normalise state and action"""

    # ------------------------------------------------------------------------------------------------------
    def __post_init__(self) -> None:
        super().__post_init__()
        H, W = self.image_hw
        if self.patch_size <= 0 or H % self.patch_size or W % self.patch_size:
            raise ValueError(f"image_hw {self.image_hw} is not divisible into {self.patch_size} px patches")
        if self.patch_size % self.stem_stride:
            raise ValueError(
                f"patch_size {self.patch_size} must be a multiple of stem_stride {self.stem_stride}"
            )
        if self.dim % self.heads:
            raise ValueError(f"dim {self.dim} must be divisible by heads {self.heads}")
        if not 1 <= self.n_action_steps <= self.chunk:
            raise ValueError(f"need 1 <= n_action_steps ({self.n_action_steps}) <= chunk ({self.chunk})")
        if self.attention not in ("math", "sdpa"):
            raise ValueError(f"unknown attention {self.attention!r}; use 'math' or 'sdpa'")
        if self.head not in ("l1", "flow"):
            raise ValueError(f"unknown action head {self.head!r}; use 'l1' or 'flow'")

    @property
    def grid_hw(self) -> tuple[int, int]:
        return self.image_hw[0] // self.patch_size, self.image_hw[1] // self.patch_size

    @property
    def n_patches(self) -> int:
        h, w = self.grid_hw
        return h * w

    @property
    def resolved(self) -> bool:
        return super().resolved and self.vocab_size > 0

    def data_fields(self) -> dict[str, Any]:
        return {**super().data_fields(), "vocab_size": self.vocab_size}


def tiny() -> VLAConfig:
    """CPU-sized (about 0.6 M parameters): 96 px -> 8 x 8 tokens, width 128, 4 layers, chunks of 4."""
    return VLAConfig()


def large() -> VLAConfig:
    """GPU-sized: 224 px -> 16 x 16 tokens of 14 px (a ViT-L/14-like grid), width 512, 8 layers, chunks of 10."""
    return VLAConfig(
        image_hw=(224, 224),
        patch_size=14,
        stem_stride=2,
        stem_channels=64,
        dim=512,
        depth=8,
        heads=8,
        mlp_ratio=4.0,
        max_text_len=32,
        chunk=10,
        n_action_steps=5,
        attention="sdpa",
    )


PRESETS = {"tiny": tiny, "large": large}
"""the policy sizes (`gazereg presets`)"""
