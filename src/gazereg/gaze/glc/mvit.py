"""Building blocks of the GLC network: an MViT (v1) backbone with a leading global token.

Token tensors are `(B, N, C)` with `N = n_global + T*H*W`: the global token(s) come first, then the
space-time grid flattened in (t, h, w) order. Every block takes and returns the grid shape `thw`.

One attention class and one block class cover the three block kinds of GLC:

* encoder block: q optionally pooled (strided depth-wise Conv3d), k/v pooled, max-pooled skip;
* global-local correlation (GLC) block: as an encoder block, with an additive -1e8 attention mask
  (a local token sees only itself and the global token; the global token sees only itself), no skip pool;
* decoder block: q upsampled by a depth-wise ConvTranspose3d, k/v pooled, trilinearly upsampled skip.

Global tokens are never pooled/upsampled: they are split off, the grid is resampled, they are put back
in front, and only then the LayerNorm of q/k/v is applied (so the global token is normalised too).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import torch
import torch.nn.functional as F
from torch import nn

Triple = tuple[int, int, int]
THW = tuple[int, int, int]

GLC_MASK_VALUE = 1e8
"""Magnitude of the additive attention mask of the global-local correlation block."""


def _is_identity(kernel: Sequence[int], stride: Sequence[int]) -> bool:
    return all(k == 1 for k in kernel) and all(s == 1 for s in stride)


class DropPath(nn.Module):
    """Stochastic depth: drop the whole residual branch of a sample with probability `p` (train only)."""

    def __init__(self, p: float = 0.0) -> None:
        super().__init__()
        self.p = float(p)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.p == 0.0 or not self.training:
            return x
        keep = 1.0 - self.p
        mask = x.new_empty((x.shape[0],) + (1,) * (x.ndim - 1)).bernoulli_(keep)
        return x * mask / keep

    def extra_repr(self) -> str:
        return f"p={self.p}"


class Mlp(nn.Module):
    """`fc1 -> GELU -> fc2` (hidden width and output width are free)."""

    def __init__(self, dim_in: int, hidden: int, dim_out: int) -> None:
        super().__init__()
        self.fc1 = nn.Linear(dim_in, hidden)
        self.act = nn.GELU()
        self.fc2 = nn.Linear(hidden, dim_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(self.act(self.fc1(x)))


def resample_tokens(
    x: torch.Tensor,
    op: nn.Module | None,
    thw: THW,
    n_global: int,
    norm: nn.Module | None = None,
) -> tuple[torch.Tensor, THW]:
    """Apply a 3-D op (pool, conv, upsample) to the grid tokens of `x`, leaving the global tokens out.

    Args:
        x: `(B, N, C)` or `(B, heads, N, C)` with `N = n_global + T*H*W`.
        op: module mapping `(B', C, T, H, W)` to `(B', C, T', H', W')`; None returns `x` unchanged.
        thw: the grid shape `(T, H, W)` of `x`.
        n_global: number of leading global tokens, passed through untouched.
        norm: optional LayerNorm applied afterwards to every token (global ones included).

    Returns:
        The resampled tokens (same rank as `x`, `N' = n_global + T'*H'*W'`) and the new `(T', H', W')`.
    """
    if op is None:
        return x, thw
    squeeze = x.ndim == 3
    if squeeze:
        x = x.unsqueeze(1)
    glob, grid = x[:, :, :n_global], x[:, :, n_global:]
    b, h, _, c = grid.shape
    t, hh, ww = thw
    grid = grid.reshape(b * h, t, hh, ww, c).permute(0, 4, 1, 2, 3)
    grid = op(grid)
    new_thw = (int(grid.shape[2]), int(grid.shape[3]), int(grid.shape[4]))
    grid = grid.reshape(b, h, c, -1).transpose(2, 3)
    x = torch.cat((glob, grid), dim=2)
    if norm is not None:
        x = norm(x)
    if squeeze:
        x = x.squeeze(1)
    return x, new_thw


def glc_attention_mask(n_tokens: int, n_global: int, device=None, dtype=torch.float32) -> torch.Tensor:
    """Additive `(N, N)` mask of the GLC block: 0 where attention is allowed, `-1e8` elsewhere.

    Token `i` may attend to itself; a local token (index >= n_global) may also attend to every global
    token; a global token attends only to itself.
    """
    mask = torch.full((n_tokens, n_tokens), -GLC_MASK_VALUE, device=device, dtype=dtype)
    mask.fill_diagonal_(0.0)
    mask[n_global:, :n_global] = 0.0
    return mask


class PooledAttention(nn.Module):
    """Multi-head attention whose q, k, v live on resampled space-time grids (MViT pooling attention).

    `qkv` is one Linear(dim, 3*dim); per head (`head_dim = dim // num_heads`) the q grid is either
    pooled (`q_mode="pool"`: depth-wise Conv3d named `pool_q`) or upsampled (`q_mode="upsample"`:
    depth-wise ConvTranspose3d named `upsample_q`), k and v are pooled with depth-wise Conv3d
    (`pool_k`, `pool_v`); each resampled tensor gets a LayerNorm over `head_dim` (`norm_q/k/v`).
    A resampling whose kernel and stride are all 1 is skipped (no module, no norm).

    Input `(B, N, dim)` on grid `thw`; output `(B, N_q, dim)` on the q grid.
    """

    def __init__(
        self,
        dim: int,
        num_heads: int,
        *,
        qkv_bias: bool = True,
        kernel_q: Triple = (1, 1, 1),
        stride_q: Triple = (1, 1, 1),
        kernel_kv: Triple = (1, 1, 1),
        stride_kv: Triple = (1, 1, 1),
        q_mode: Literal["pool", "upsample"] = "pool",
        n_global: int = 1,
        glc_mask: bool = False,
        eps: float = 1e-6,
    ) -> None:
        super().__init__()
        if dim % num_heads:
            raise ValueError(f"dim {dim} is not divisible by num_heads {num_heads}")
        self.num_heads = num_heads
        self.n_global = n_global
        self.glc_mask = glc_mask
        head_dim = dim // num_heads
        self.scale = head_dim**-0.5
        self.qkv = nn.Linear(dim, 3 * dim, bias=qkv_bias)
        self.proj = nn.Linear(dim, dim)

        pad_q = tuple(k // 2 for k in kernel_q)
        pad_kv = tuple(k // 2 for k in kernel_kv)
        self.q_mode = q_mode
        q_op: nn.Module | None = None
        if not _is_identity(kernel_q, stride_q):
            if q_mode == "pool":
                q_op = nn.Conv3d(head_dim, head_dim, kernel_q, stride_q, pad_q, groups=head_dim, bias=False)
            elif q_mode == "upsample":
                out_pad = tuple(s - 1 for s in stride_q)
                q_op = nn.ConvTranspose3d(
                    head_dim, head_dim, kernel_q, stride_q, pad_q, out_pad, groups=head_dim, bias=False
                )
            else:
                raise ValueError(f"unknown q_mode {q_mode!r}")
        if q_mode == "pool":
            self.pool_q = q_op
        else:
            self.upsample_q = q_op
        self.norm_q = nn.LayerNorm(head_dim, eps=eps) if q_op is not None else None
        has_kv = not _is_identity(kernel_kv, stride_kv)

        def kv_conv() -> nn.Module | None:
            if not has_kv:
                return None
            return nn.Conv3d(head_dim, head_dim, kernel_kv, stride_kv, pad_kv, groups=head_dim, bias=False)

        self.pool_k = kv_conv()
        self.norm_k = nn.LayerNorm(head_dim, eps=eps) if has_kv else None
        self.pool_v = kv_conv()
        self.norm_v = nn.LayerNorm(head_dim, eps=eps) if has_kv else None

    @property
    def q_op(self) -> nn.Module | None:
        return self.pool_q if self.q_mode == "pool" else self.upsample_q

    def forward(self, x: torch.Tensor, thw: THW) -> tuple[torch.Tensor, THW]:
        b, n, c = x.shape
        qkv = self.qkv(x).reshape(b, n, 3, self.num_heads, c // self.num_heads).permute(2, 0, 3, 1, 4)
        q, k, v = qkv.unbind(0)  # each (B, heads, N, head_dim)
        q, q_thw = resample_tokens(q, self.q_op, thw, self.n_global, self.norm_q)
        k, _ = resample_tokens(k, self.pool_k, thw, self.n_global, self.norm_k)
        v, _ = resample_tokens(v, self.pool_v, thw, self.n_global, self.norm_v)
        mask = None
        if self.glc_mask:
            if q.shape[2] != k.shape[2]:
                raise ValueError("the global-local mask needs q and k on the same grid")
            mask = glc_attention_mask(q.shape[2], self.n_global, device=q.device, dtype=q.dtype)
        out = F.scaled_dot_product_attention(q, k, v, attn_mask=mask, scale=self.scale)
        out = out.transpose(1, 2).reshape(b, q.shape[2], c)
        return self.proj(out), q_thw


class MultiScaleBlock(nn.Module):
    """Pre-norm transformer block of MViT v1 on a space-time grid, with a channel change at its end.

    `x <- skip(x) + drop_path(attn(norm1(x)))`, then with `y = norm2(x)`:
    `x <- (proj(y) if dim != dim_out else x) + drop_path(mlp(y))`, `mlp: dim -> hidden -> dim_out`.

    The skip resamples `x` onto the q grid: `skip="maxpool"` (MaxPool3d, kernel `s+1` where the stride
    `s > 1`, encoder), `skip="upsample"` (trilinear, scale = q stride, decoder) or none.
    Input `(B, N, dim)` on `thw`; output `(B, N', dim_out)` on the new grid.
    """

    def __init__(
        self,
        dim: int,
        dim_out: int,
        num_heads: int,
        mlp_hidden: int,
        *,
        qkv_bias: bool = True,
        kernel_q: Triple = (1, 1, 1),
        stride_q: Triple = (1, 1, 1),
        kernel_kv: Triple = (1, 1, 1),
        stride_kv: Triple = (1, 1, 1),
        q_mode: Literal["pool", "upsample"] = "pool",
        skip: Literal["maxpool", "upsample", "none"] = "maxpool",
        glc_mask: bool = False,
        drop_path: float = 0.0,
        n_global: int = 1,
        eps: float = 1e-6,
    ) -> None:
        super().__init__()
        self.dim, self.dim_out, self.n_global = dim, dim_out, n_global
        self.norm1 = nn.LayerNorm(dim, eps=eps)
        self.attn = PooledAttention(
            dim,
            num_heads,
            qkv_bias=qkv_bias,
            kernel_q=kernel_q,
            stride_q=stride_q,
            kernel_kv=kernel_kv,
            stride_kv=stride_kv,
            q_mode=q_mode,
            n_global=n_global,
            glc_mask=glc_mask,
            eps=eps,
        )
        self.drop_path = DropPath(drop_path) if drop_path > 0 else nn.Identity()
        self.norm2 = nn.LayerNorm(dim, eps=eps)
        self.mlp = Mlp(dim, mlp_hidden, dim_out)
        if dim != dim_out:
            self.proj = nn.Linear(dim, dim_out)
        self.skip: nn.Module | None = None
        if any(s > 1 for s in stride_q) and skip == "maxpool":
            k_skip = tuple(s + 1 if s > 1 else s for s in stride_q)
            self.skip = nn.MaxPool3d(k_skip, stride_q, tuple(k // 2 for k in k_skip))
        elif any(s > 1 for s in stride_q) and skip == "upsample":
            self.skip = nn.Upsample(scale_factor=tuple(float(s) for s in stride_q), mode="trilinear")

    def forward(self, x: torch.Tensor, thw: THW) -> tuple[torch.Tensor, THW]:
        x_attn, new_thw = self.attn(self.norm1(x), thw)
        x_res, _ = resample_tokens(x, self.skip, thw, self.n_global)
        x = x_res + self.drop_path(x_attn)
        y = self.norm2(x)
        if self.dim != self.dim_out:
            x = self.proj(y)
        return x + self.drop_path(self.mlp(y)), new_thw


class PatchEmbed(nn.Module):
    """Conv3d patch embedding: `(B, C, T, H, W) -> (B, dim, T', H', W')` (kept as a map)."""

    def __init__(self, dim_in: int, dim_out: int, kernel: Triple, stride: Triple, padding: Triple) -> None:
        super().__init__()
        self.proj = nn.Conv3d(dim_in, dim_out, kernel, stride, padding)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj(x)


class GlobalEmbed(nn.Module):
    """The global token: BN+ReLU on the patch-embedding map, then `n_convs` Conv3d(k=3, stride (1,2,2))
    with BN+ReLU between them (not after the last), then a Linear on the flattened `(C, T, H, W)` map.

    `(B, dim, T, H, W) -> (B, 1, dim_token)`; `grid` is the `(T, H, W)` after the convs (fixes the
    Linear's input width `dim * T * H * W`).
    """

    def __init__(self, dim: int, dim_token: int, grid: THW, n_convs: int = 3) -> None:
        super().__init__()
        self.n_convs = n_convs
        self.relu = nn.ReLU()
        self.bn_0 = nn.BatchNorm3d(dim)
        for i in range(1, n_convs + 1):
            self.add_module(f"proj_{i}", nn.Conv3d(dim, dim, 3, (1, 2, 2), 1))
            if i < n_convs:
                self.add_module(f"bn_{i}", nn.BatchNorm3d(dim))
        self.linear = nn.Linear(dim * grid[0] * grid[1] * grid[2], dim_token)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.relu(self.bn_0(x))
        for i in range(1, self.n_convs + 1):
            x = getattr(self, f"proj_{i}")(x)
            if i < self.n_convs:
                x = self.relu(getattr(self, f"bn_{i}")(x))
        return self.linear(x.flatten(1)).unsqueeze(1)
