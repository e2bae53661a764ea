"""The reference VLA's building blocks: the conv stem, the transformer block and the flow-time embedding.

Shapes: B batch, T tokens, D width, H heads, d = D / H, N patches per image.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from gazereg.attention.probe import tap
from gazereg.policies.vla.configuration_vla import VLAConfig


class ConvStem(nn.Module):
    """(B, 3, H, W) -> (B, N, D) patch tokens: stride-s patchify conv, 3x3 conv, stride-(p/s) conv."""

    def __init__(self, cfg: VLAConfig):
        super().__init__()
        c, s = cfg.stem_channels, cfg.stem_stride
        self.net = nn.Sequential(
            nn.Conv2d(3, c, kernel_size=s, stride=s),
            nn.GELU(),
            nn.Conv2d(c, c, kernel_size=3, padding=1),
            nn.GELU(),
            nn.Conv2d(c, cfg.dim, kernel_size=cfg.patch_size // s, stride=cfg.patch_size // s),
        )

    def forward(self, x: Tensor) -> Tensor:
        return self.net(x).permute(0, 2, 3, 1).flatten(1, 2)  # a view for channels-last maps


def attention_bias(mask: Tensor) -> Tensor:
    """Bool mask (B, 1, T, T) (True = may attend) -> the additive float32 bias: 0 where allowed, -inf elsewhere."""
    return torch.zeros(mask.shape, dtype=torch.float32, device=mask.device).masked_fill_(~mask, float("-inf"))


class Attention(nn.Module):
    """Multi-head self-attention. `impl` "math": softmax(q k^T / sqrt(d) + bias) V written out, in the compute
    dtype (bf16 under autocast; the softmax accumulates in float32); "sdpa": `F.scaled_dot_product_attention`
    (fused kernels for long sequences and GPUs). Both compute the same function; which is faster depends on
    the machine (benchmarks/bench_train.py)."""

    def __init__(self, dim: int, heads: int, layer: int, dropout: float, impl: str = "math"):
        super().__init__()
        self.heads, self.layer, self.dropout, self.impl = heads, layer, dropout, impl
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)

    def forward(
        self, x: Tensor, mask: Tensor, output_attentions: bool = False, bias: Tensor | None = None
    ) -> tuple[Tensor, Tensor | None]:
        """x (B, T, D), mask (B, 1, T, T) bool (True = may attend), optionally its `attention_bias` (computed
        once for all layers) -> (B, T, D) [, probs (B, H, T, T) float32 if output_attentions]."""
        B, T, D = x.shape
        q, k, v = (
            self.qkv(x).reshape(B, T, 3, self.heads, D // self.heads).permute(2, 0, 3, 1, 4)
        )  # (B, H, T, d)
        tap(self.layer, q, k, mask)  # free unless an AttentionProbe is active
        p = self.dropout if self.training else 0.0
        if self.impl == "sdpa" and not output_attentions:
            y = F.scaled_dot_product_attention(q, k, v, attn_mask=mask, dropout_p=p)
            return self.proj(y.transpose(1, 2).reshape(B, T, D)), None
        bias = attention_bias(mask) if bias is None else bias
        logits = (q * (1.0 / math.sqrt(D // self.heads))) @ k.transpose(-1, -2) + bias.to(q.dtype)
        probs = torch.softmax(logits, dim=-1)  # accumulates in float32 whatever the dtype
        y = (F.dropout(probs, p) if p > 0 else probs) @ v
        return self.proj(y.transpose(1, 2).reshape(B, T, D)), probs.float() if output_attentions else None


class Block(nn.Module):
    def __init__(self, cfg: VLAConfig, layer: int):
        super().__init__()
        self.norm1 = nn.LayerNorm(cfg.dim)
        self.attn = Attention(cfg.dim, cfg.heads, layer, cfg.dropout, cfg.attention)
        self.norm2 = nn.LayerNorm(cfg.dim)
        hidden = int(cfg.dim * cfg.mlp_ratio)
        self.mlp = nn.Sequential(
            nn.Linear(cfg.dim, hidden), nn.GELU(), nn.Linear(hidden, cfg.dim), nn.Dropout(cfg.dropout)
        )

    def forward(
        self, x: Tensor, mask: Tensor, output_attentions: bool = False, bias: Tensor | None = None
    ) -> tuple[Tensor, Tensor | None]:
        y, probs = self.attn(self.norm1(x), mask, output_attentions, bias)
        x = x + y
        return x + self.mlp(self.norm2(x)), probs


def flow_time_embedding(t: Tensor, dim: int) -> Tensor:
    """Sinusoidal embedding of flow times t (B,) in [0, 1] -> (B, dim)."""
    half = dim // 2
    freqs = torch.exp(-math.log(1000.0) * torch.arange(half, device=t.device, dtype=torch.float32) / half)
    ang = t.float()[:, None] * 1000.0 * freqs[None]
    return torch.cat([ang.sin(), ang.cos()], -1)
