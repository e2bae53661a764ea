"""GLC: egocentric gaze estimation with Global-Local Correlation (Lai et al., ECCV 2022 / IJCV).

A clean re-implementation of the official `GLC_Gaze` model (MViT-B 16x4 conv backbone + global token +
GLC block + transformer decoder) whose `state_dict()` has exactly the official names and shapes, so the
released SlowFast checkpoints load strictly (see `gazereg.gaze.glc.checkpoint`).

Data flow for `GLCConfig.official()` (B = batch, global token first in every token tensor):

    clip (B,3,8,256,256) --patch_embed Conv3d k(3,7,7) s(2,4,4)--> map (B,96,4,64,64)
    global_embed(map) -> (B,1,96)                       [BN+ReLU, 3 strided convs, Linear]
    tokens = map tokens + spatial pos + temporal pos    (B,16384,96); x = [global, tokens]
    16 MViT blocks (q stride (1,2,2) at blocks 1,3,14)  -> (B,1+4*8*8,768); skips after blocks 0,2,13
    global_fuse (GLC block, masked attention); concat [x, fused] -> (B,257,1536) -> LayerNorm
    decode_block1..3: q upsampled (1,2,2), + skip       -> (B,1+4*64*64,192)
    decode_block4: q upsampled (2,1,1)                  -> (B,1+8*64*64,96)
    drop global token, + trilinear(patch-embed tokens incl. pos, to 8x64x64), Conv3d 1x1x1 -> (B,1,8,64,64)
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from gazereg.gaze.glc.mvit import THW, GlobalEmbed, MultiScaleBlock, PatchEmbed, Triple


def _conv_out(n: int, k: int, s: int, p: int) -> int:
    return (n + 2 * p - k) // s + 1


@dataclass(frozen=True)
class GLCConfig:
    """Architecture of a GLC network. `full()` is the official model, `small()` a CPU-sized variant.

    Encoder: `depth` MViT blocks; at each block index in `q_stride_blocks` q is pooled by `q_stride` and
    channels and heads double (the block before it projects to the doubled width); k/v are pooled with
    the adaptive stride `kv_stride_adaptive` divided by the q strides seen so far.
    Decoder: one block per q stride (upsampling by `q_stride`), then one temporal block upsampling by
    `patch_stride[0]`; `decoder_heads` and `decoder_kv_strides` have one entry per decoder block.
    """

    num_frames: int = 8
    crop_size: int = 256
    in_chans: int = 3
    embed_dim: int = 96
    num_heads: int = 1
    depth: int = 16
    mlp_ratio: float = 4.0
    qkv_bias: bool = True
    patch_kernel: Triple = (3, 7, 7)
    patch_stride: Triple = (2, 4, 4)
    patch_padding: Triple = (1, 3, 3)
    pool_kernel: Triple = (3, 3, 3)
    q_stride_blocks: tuple[int, ...] = (1, 3, 14)
    q_stride: Triple = (1, 2, 2)
    kv_stride_adaptive: Triple = (1, 8, 8)
    global_embed_convs: int = 3
    decoder_heads: tuple[int, ...] = (8, 4, 4, 2)
    decoder_kv_strides: tuple[Triple, ...] = ((1, 2, 2), (1, 4, 4), (1, 8, 8), (1, 16, 16))
    drop_path_rate: float = 0.2
    glc_drop_path: float = 0.4
    norm_eps: float = 1e-6
    mean: float = 0.45
    std: float = 0.225
    temperature: float = 2.0

    def __post_init__(self) -> None:
        n_dec = len(self.q_stride_blocks) + 1
        if len(self.decoder_heads) != n_dec or len(self.decoder_kv_strides) != n_dec:
            raise ValueError(f"decoder_heads and decoder_kv_strides need {n_dec} entries")
        if any(b < 1 or b >= self.depth for b in self.q_stride_blocks):
            raise ValueError("q_stride_blocks must lie in [1, depth)")
        if list(self.q_stride_blocks) != sorted(set(self.q_stride_blocks)):
            raise ValueError("q_stride_blocks must be strictly increasing")

    # ---- presets -------------------------------------------------------------------------------
    @classmethod
    def official(cls) -> GLCConfig:
        """Official GLC (MViT-B 16x4 conv): input (B,3,8,256,256) -> logits (B,1,8,64,64); 70.18 M params."""
        return cls()

    @classmethod
    def full(cls) -> GLCConfig:
        """The official size's former name (`official`)."""
        return cls.official()

    @classmethod
    def small(cls) -> GLCConfig:
        """Same code, narrow and shallow: input (B,3,8,96,96) -> logits (B,1,8,24,24); ~3.5 M params."""
        return cls(
            crop_size=96,
            embed_dim=48,
            num_heads=1,
            depth=5,
            q_stride_blocks=(1, 3),
            decoder_heads=(4, 2, 1),
            decoder_kv_strides=((1, 2, 2), (1, 4, 4), (1, 8, 8)),
            drop_path_rate=0.1,
            glc_drop_path=0.2,
        )

    # ---- derived shapes ------------------------------------------------------------------------
    @property
    def input_shape(self) -> tuple[int, int, int, int]:
        """`(C, T, H, W)` of one input clip."""
        return (self.in_chans, self.num_frames, self.crop_size, self.crop_size)

    @property
    def token_grid(self) -> THW:
        """`(T, H, W)` of the patch-embedding map."""
        size = (self.num_frames, self.crop_size, self.crop_size)
        k, s, p = self.patch_kernel, self.patch_stride, self.patch_padding
        return tuple(_conv_out(size[i], k[i], s[i], p[i]) for i in range(3))  # type: ignore[return-value]

    @property
    def output_shape(self) -> THW:
        """`(T, h, w)` of the output logit map: token grid with time upsampled by `patch_stride[0]`."""
        t, h, w = self.token_grid
        return (t * self.patch_stride[0], h, w)

    @property
    def global_grid(self) -> THW:
        """`(T, H, W)` after the strided convs of the global embedding."""
        t, h, w = self.token_grid
        for _ in range(self.global_embed_convs):
            h, w = _conv_out(h, 3, 2, 1), _conv_out(w, 3, 2, 1)
        return (t, h, w)

    def block_specs(self) -> list[dict[str, Any]]:
        """Per encoder block: dim, dim_out, heads, q stride and kv stride."""
        specs = []
        stage_of = [sum(b <= i for b in self.q_stride_blocks) for i in range(self.depth + 1)]
        stage_of[self.depth] = stage_of[self.depth - 1]
        kv = tuple(self.kv_stride_adaptive)
        for i in range(self.depth):
            strided = i in self.q_stride_blocks
            if strided:
                kv = tuple(max(kv[d] // self.q_stride[d], 1) for d in range(3))
            specs.append(
                dict(
                    dim=self.embed_dim * 2 ** stage_of[i],
                    dim_out=self.embed_dim * 2 ** stage_of[i + 1],
                    heads=self.num_heads * 2 ** stage_of[i],
                    stride_q=tuple(self.q_stride) if strided else (1, 1, 1),
                    stride_kv=kv,
                )
            )
        return specs

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> GLCConfig:
        """Inverse of `to_dict` (lists from JSON become tuples)."""

        def tup(v: Any) -> Any:
            return tuple(tup(x) for x in v) if isinstance(v, list | tuple) else v

        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown GLCConfig fields: {sorted(unknown)}")
        return cls(**{k: tup(v) for k, v in d.items()})

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)


def _encoder_blocks(cfg: GLCConfig, specs: list[dict[str, Any]]) -> nn.ModuleList:
    """The MViT encoder blocks (drop-path rising linearly from 0 to `cfg.drop_path_rate`)."""
    dpr = torch.linspace(0, cfg.drop_path_rate, cfg.depth).tolist()
    kq = cfg.pool_kernel
    return nn.ModuleList(
        MultiScaleBlock(
            s["dim"],
            s["dim_out"],
            s["heads"],
            int(s["dim"] * cfg.mlp_ratio),
            qkv_bias=cfg.qkv_bias,
            kernel_q=kq if s["stride_q"] != (1, 1, 1) else (1, 1, 1),
            stride_q=s["stride_q"],
            kernel_kv=kq,
            stride_kv=s["stride_kv"],
            skip="maxpool",
            drop_path=dpr[i],
            eps=cfg.norm_eps,
        )
        for i, s in enumerate(specs)
    )


def _decoder_blocks(cfg: GLCConfig, specs: list[dict[str, Any]]) -> list[MultiScaleBlock]:
    """The decoder blocks, coarsest first: each upsamples the queries and adds the matching encoder stage
    (the last one the patch embedding), down to `cfg.embed_dim` channels."""
    d_last = specs[-1]["dim_out"]
    skip_dims = [cfg.embed_dim] + [specs[b - 1]["dim_out"] for b in cfg.q_stride_blocks]
    dec_out = skip_dims[::-1]
    dec_in = [2 * d_last] + dec_out[:-1]
    dec_stride_q = [tuple(cfg.q_stride)] * len(cfg.q_stride_blocks) + [(cfg.patch_stride[0], 1, 1)]
    return [
        MultiScaleBlock(
            dec_in[j],
            dec_out[j],
            cfg.decoder_heads[j],
            int(dec_out[j] * cfg.mlp_ratio),
            qkv_bias=cfg.qkv_bias,
            kernel_q=cfg.pool_kernel,
            stride_q=dec_stride_q[j],
            kernel_kv=cfg.pool_kernel,
            stride_kv=tuple(cfg.decoder_kv_strides[j]),
            q_mode="upsample",
            skip="upsample",
            eps=cfg.norm_eps,
        )
        for j in range(len(dec_in))
    ]


class GLC(nn.Module):
    """The GLC gaze estimator. `forward(x: (B,3,T,H,W) normalised clip) -> logits (B,1,T,h,w)`.

    `T, H, W` must equal `cfg.num_frames, cfg.crop_size, cfg.crop_size`; `(T, h, w) = cfg.output_shape`
    (8x64x64 for the full model). Use `prepare_clip` to go from raw frames to the normalised input, and
    `heatmaps` for per-frame probability maps (softmax over h*w of `logits / 2`).
    """

    def __init__(self, cfg: GLCConfig | None = None) -> None:
        super().__init__()
        cfg = cfg if cfg is not None else GLCConfig.official()
        self.cfg = cfg
        e = cfg.embed_dim
        t, h, w = cfg.token_grid
        self.pos_embed_spatial = nn.Parameter(torch.zeros(1, h * w, e))
        self.pos_embed_temporal = nn.Parameter(torch.zeros(1, t, e))
        self.patch_embed = PatchEmbed(cfg.in_chans, e, cfg.patch_kernel, cfg.patch_stride, cfg.patch_padding)
        self.global_embed = GlobalEmbed(e, e, cfg.global_grid, cfg.global_embed_convs)

        specs = cfg.block_specs()
        self.blocks = _encoder_blocks(cfg, specs)
        self.stage_ends = tuple(b - 1 for b in cfg.q_stride_blocks)
        d_last, heads_last = specs[-1]["dim_out"], specs[-1]["heads"]
        kq = cfg.pool_kernel
        self.global_fuse = MultiScaleBlock(
            d_last,
            d_last,
            heads_last,
            int(d_last * cfg.mlp_ratio),
            qkv_bias=cfg.qkv_bias,
            kernel_q=kq,
            kernel_kv=kq,
            skip="none",
            glc_mask=True,
            drop_path=cfg.glc_drop_path,
            eps=cfg.norm_eps,
        )
        self.norm = nn.LayerNorm(2 * d_last, eps=cfg.norm_eps)
        decoder = _decoder_blocks(cfg, specs)
        self.num_decoder_blocks = len(decoder)
        for j, block in enumerate(decoder):
            self.add_module(f"decode_block{j + 1}", block)
        self.classifier = nn.Conv3d(e, 1, kernel_size=1)
        self._init_weights()

    def _init_weights(self) -> None:
        nn.init.trunc_normal_(self.pos_embed_spatial, std=0.02)
        nn.init.trunc_normal_(self.pos_embed_temporal, std=0.02)
        for m in self.modules():
            if isinstance(m, nn.Linear):
                nn.init.trunc_normal_(m.weight, std=0.02)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
            elif isinstance(m, nn.LayerNorm):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)

    @property
    def decoder_blocks(self) -> list[MultiScaleBlock]:
        return [getattr(self, f"decode_block{j + 1}") for j in range(self.num_decoder_blocks)]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Normalised clip `(B, 3, T, H, W)` -> gaze logits `(B, 1, T, h, w)` (`cfg.output_shape`)."""
        if tuple(x.shape[1:]) != self.cfg.input_shape:
            raise ValueError(
                f"expected input (B, {', '.join(map(str, self.cfg.input_shape))}), got {tuple(x.shape)}"
            )
        fmap = self.patch_embed(x)  # (B, E, T, H, W)
        b, e, t, h, w = fmap.shape
        glob = self.global_embed(fmap)  # (B, 1, E)
        pos = self.pos_embed_spatial.repeat(1, t, 1) + self.pos_embed_temporal.repeat_interleave(h * w, dim=1)
        x = torch.cat((glob, fmap.flatten(2).transpose(1, 2) + pos), dim=1)
        thw: THW = (t, h, w)

        skips = [x]
        for i, blk in enumerate(self.blocks):
            x, thw = blk(x, thw)
            if i in self.stage_ends:
                skips.append(x)
        fused, _ = self.global_fuse(x, thw)
        x = self.norm(torch.cat((x, fused), dim=2))

        for j, blk in enumerate(self.decoder_blocks):
            x, thw = blk(x, thw)
            if j < self.num_decoder_blocks - 1:
                x = x + skips[-1 - j]
        x = x[:, 1:].reshape(b, *thw, -1).permute(0, 4, 1, 2, 3)
        x0 = skips[0][:, 1:].reshape(b, t, h, w, e).permute(0, 4, 1, 2, 3)
        x = x + F.interpolate(x0, size=thw, mode="trilinear", align_corners=False)
        return self.classifier(x)

    def heatmaps(self, x: torch.Tensor, temperature: float | None = None) -> torch.Tensor:
        """Per-frame gaze probability maps `(B, T, h, w)`: softmax over h*w of `logits / temperature`
        (default `cfg.temperature` = 2, as in the official evaluation)."""
        return frame_softmax(self(x), self.cfg.temperature if temperature is None else temperature)

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())


def frame_softmax(logits: torch.Tensor, temperature: float = 2.0) -> torch.Tensor:
    """`(B, 1, T, h, w)` or `(B, T, h, w)` logits -> `(B, T, h, w)` maps, each frame summing to 1."""
    if logits.ndim == 5:
        logits = logits.squeeze(1)
    b, t, h, w = logits.shape
    return torch.softmax(logits.reshape(b, t, h * w) / temperature, dim=-1).reshape(b, t, h, w)


def prepare_clip(clip: torch.Tensor, cfg: GLCConfig) -> torch.Tensor:
    """Raw clip -> normalised model input.

    Args:
        clip: `(B, 3, T, H, W)` (or `(3, T, H, W)`), uint8 in [0, 255] or float in [0, 1].
        cfg: gives the crop size and the normalisation (mean 0.45, std 0.225 for every channel).

    Returns:
        float32 `(B, 3, T, S, S)`, `S = cfg.crop_size`. Frames of another size are resized whole
        (bilinear, no crop), so normalised gaze coordinates stay valid.
    """
    if clip.ndim == 4:
        clip = clip.unsqueeze(0)
    x = clip.float() / 255.0 if clip.dtype == torch.uint8 else clip.float()
    b, c, t, h, w = x.shape
    s = cfg.crop_size
    if (h, w) != (s, s):
        frames = x.permute(0, 2, 1, 3, 4).reshape(b * t, c, h, w)
        frames = F.interpolate(frames, size=(s, s), mode="bilinear", align_corners=False, antialias=True)
        x = frames.reshape(b, t, c, s, s).permute(0, 2, 1, 3, 4)
    return (x - cfg.mean) / cfg.std
