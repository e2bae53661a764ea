"""The core library in one page: gaze points -> heatmaps -> temporal aggregation -> patch distributions
-> the gaze KL on a toy transformer's attention, captured by the probe. Runs in about a second on a CPU.

    python examples/core_api.py
"""

import torch
import torch.nn.functional as F
from torch import nn

from gazereg import (
    AggregationConfig,
    AttentionProbe,
    PatchGeometry,
    ProbeSpec,
    aggregate,
    gaze_loss,
    heatmaps_from_points,
    patch_distribution,
)
from gazereg.attention import tap

torch.manual_seed(0)
T, n_patches, dim = 12, 16, 32

# 1. Per-frame gaze points (u right, v down, normalised) drifting across the image; frame 5 lost (NaN).
points = torch.stack([torch.linspace(0.2, 0.7, T), torch.full((T,), 0.6)], -1)
points[5] = float("nan")
heat, valid = heatmaps_from_points(points, size=(64, 64), sigma=3.2)  # (T, 64, 64), (T,)

# 2. Aggregate over a centred window of 2 past and 2 future frames (frame 5 is filled by its neighbours).
heat, valid = aggregate(heat, valid, AggregationConfig(past=2, future=2, kernel="gaussian", sigma=1.0))

# 3. Onto the policy's patch grid: a 64x64 input cut into 16 px patches (a 4x4 grid).
geometry = PatchGeometry(input_hw=(64, 64), patch_size=16)
gaze, valid = patch_distribution(heat, geometry, valid)  # (T, 16), (T,)


# 4. A toy policy: 16 patch tokens + 2 action queries, fused attention that taps its q and k.
class Block(nn.Module):
    def __init__(self, layer: int):
        super().__init__()
        self.layer, self.qkv, self.out = layer, nn.Linear(dim, 3 * dim), nn.Linear(dim, dim)

    def forward(self, x):
        B, N, _ = x.shape
        q, k, v = self.qkv(x).reshape(B, N, 3, 4, dim // 4).permute(2, 0, 3, 1, 4)
        tap(self.layer, q, k)  # free unless a probe is active
        return x + self.out(F.scaled_dot_product_attention(q, k, v).transpose(1, 2).reshape(B, N, dim))


model = nn.Sequential(Block(0), Block(1))
tokens = torch.randn(T, n_patches + 2, dim)
spec = ProbeSpec(queries=slice(n_patches, n_patches + 2), keys=slice(0, n_patches), layers=(1,))
opt = torch.optim.AdamW(model.parameters(), lr=3e-3)
for step in range(60):
    with AttentionProbe(model, spec) as probe:
        out = model(tokens)
    action_loss = out[:, n_patches:].pow(2).mean()  # stand-in for the policy's action loss
    kl, info = gaze_loss(gaze, probe.distribution(), valid)
    loss = action_loss + 1.0 * kl
    opt.zero_grad()
    loss.backward()
    opt.step()
    if step % 20 == 0 or step == 59:
        print(f"step {step:2d}  action {action_loss.item():.4f}  KL(gaze||attention) {kl.item():.4f}")
