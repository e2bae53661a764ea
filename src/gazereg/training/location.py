"""The location control (`--gaze.target features`): the gaze term's target predicted by a training-only head
from the policy's image-token features instead of read from its attention.

Does the gaze arm help by supervising *attention*, or by handing the policy the prior's privileged *location*
information (issue #21, item 6)? This arm gets the same information: the same target (the gaze prior over
the gaze camera's patches, with its validity mask), the same divergence and eps (`gaze.divergence`,
`gaze.loss_eps`) and the same weight schedule (`gaze.weight`, `gaze.schedule`, ...), but compares the gaze
with a distribution predicted from features instead of the action queries' attention:

    head_b(n) = softmax_n( w . h_{b,n} )     h_{b,n}: the output features (D) of the last layer of
                                             `gaze.layers` at patch token n of the gaze camera; w in R^D
    L = L_action + w(step) * mean_{valid b} KL(gaze_b || head_b)

Which features: the output of the deepest probed layer for the patch tokens the attention probe reads as
keys (`gaze_probe_spec(camera, layers).keys`), taken by a forward hook on `Policy.layer_module(layer)`. That
is the same depth the attention mode regularises, and under the VLA's pi0-style block mask image tokens never
attend to the action queries, so the term cannot reach the action-query side of the policy (query
embeddings, action head, final norm): its gradient reaches the shared trunk through the image tokens only,
putting location information into the features (and so the keys and values) the action queries read. Their
attention is not supervised, but it may still drift towards the gaze through those keys (the action loss
may find the marked patches useful): the logged attention KL measures how far.

The head is `Linear(D, 1)` without a bias (a constant under the softmax); its weight is drawn like the VLA's
linear layers (truncated normal, std 0.02) from a generator seeded by the run's seed, so building it draws
nothing from the global RNG. D is read from one no-grad, eval-mode forward on one training sample at setup.
The head exists only when a run trains with a prior, `gaze.enabled` and target features; it is used only in
the training loss (and the logged validation KL), never by the action path: `select_action` and the saved
policy (model.safetensors, config.json) are those of any other run; checkpoints keep the head in
training_state/ (gazereg.training.checkpoint) and `--resume` restores it. Evaluations read it on the
evaluation policy's features (the EMA weights when EMA is on; the head itself has no EMA).

Logged: `loss/location_kl` (the head's KL, the term added to the loss) and, at evaluations,
`val/location_kl`; the attention's KL stays a detached diagnostic under its usual names (`loss/gaze_kl`,
`gaze/patch_mass`, `val/gaze_kl`, `align_val/*`) so both arms' attention alignment compare directly.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor, nn

from gazereg.attention.probe import ProbeSpec
from gazereg.policies import Policy
from gazereg.training.schedule import step_generator

HEAD_NAME = "location_head"
"""the head's name in checkpoints (training_state/aux_location_head.safetensors)"""


def select_tokens(x: Tensor, keys: Any) -> Tensor:
    """Token features x (B, T, D) at positions `keys` (a slice, a list or (n,) tensor, or a (B, n) tensor of
    per-sample positions, as in `ProbeSpec.keys`) -> (B, n, D)."""
    if isinstance(keys, slice):
        return x[:, keys]
    idx = torch.as_tensor(keys, dtype=torch.long, device=x.device)
    if idx.ndim == 2:
        return torch.gather(x, 1, idx[..., None].expand(-1, -1, x.shape[-1]))
    return x[:, idx]


class FeatureCapture:
    """Context manager: a forward hook on `policy.layer_module(layer)` for the last of `spec.layers` keeps the
    features of `spec.keys` (one camera's patch tokens) from that layer's output, in `features()` (B, N, D).
    The forward is untouched; a layer run twice keeps its last call."""

    def __init__(self, policy: Policy, spec: ProbeSpec):
        if not spec.layers:
            raise ValueError("the location head needs the probe spec's layers")
        self.layer, self.keys = spec.layers[-1], spec.keys
        self.module = policy.layer_module(self.layer)
        self._features: Tensor | None = None
        self._handle: Any = None

    def __enter__(self) -> FeatureCapture:
        self._features = None
        self._handle = self.module.register_forward_hook(self._hook)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._handle is not None:
            self._handle.remove()
            self._handle = None

    def _hook(self, module: nn.Module, args: Any, output: Any) -> None:
        x = output[0] if isinstance(output, tuple | list) else output
        self._features = select_tokens(x, self.keys)

    def features(self) -> Tensor:
        if self._features is None:
            raise RuntimeError(f"layer {self.layer} did not run in the captured forward")
        return self._features


class LocationHead(nn.Module):
    """(B, N, D) patch token features -> (B, N) float32 distribution over the patches: softmax(w . h)."""

    def __init__(self, dim: int, seed: int):
        super().__init__()
        self.score = nn.Linear(dim, 1, bias=False)
        gen = torch.Generator().manual_seed(seed)
        with torch.no_grad():
            nn.init.trunc_normal_(self.score.weight, std=0.02, generator=gen)

    def forward(self, features: Tensor) -> Tensor:
        with torch.autocast(features.device.type, enabled=False):  # float32 under bf16 autocast too
            logits = self.score(features.float()).squeeze(-1)
        return torch.softmax(logits, dim=-1)


@torch.no_grad()
def feature_dim(policy: Policy, spec: ProbeSpec, batch: Mapping[str, Tensor]) -> int:
    """D of the captured features: one eval-mode forward without gradient (its random draws, if any, from a
    throwaway generator: the global RNG and the policy's state are left as they were)."""
    was_training = policy.training
    policy.eval()
    try:
        with FeatureCapture(policy, spec) as capture:
            policy(batch, generator=step_generator(0, -2, 0, policy.device))
        return int(capture.features().shape[-1])
    finally:
        policy.train(was_training)


def make_location_head(
    policy: Policy, spec: ProbeSpec, batch: Mapping[str, Tensor], seed: int
) -> LocationHead:
    """The head for `policy`'s features at the last of `spec.layers`, on the policy's device."""
    return LocationHead(feature_dim(policy, spec, batch), seed).to(policy.device)


def average_gradients(head: nn.Module, acc: Any) -> None:
    """Mean of the head's gradients over processes (the head is not inside the policy's DDP wrapper)."""
    if acc.num_processes > 1:
        for p in head.parameters():
            if p.grad is not None:
                p.grad = acc.reduce(p.grad, "mean")
