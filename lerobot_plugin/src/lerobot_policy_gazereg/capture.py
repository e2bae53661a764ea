"""Differentiable capture of SmolVLA's action-expert attention to one camera's image tokens.

SmolVLA (`SmolVLMWithExpertModel`) always computes attention with its own `eager_attention_forward`, which builds
the probabilities and returns only the output. Inside `SmolVLACapture.capture()` four methods of the model
instance are wrapped (instance attributes shadowing the class methods, removed on exit; nothing is copied):

- `embed_image`: counts the image tokens each camera produces (prefix layout);
- `forward_attn_layer` / `forward_cross_attn_layer`: note the layer index and where the expert's queries are
  (joint self-attention: the last `suffix_len` query rows; cross-attention: the expert's own call);
- `eager_attention_forward`: runs the original (outputs bit-identical) and hands the expert's query rows, the
  keys and the mask to a `gazereg.attention.AttentionProbe`, which recomputes softmax(q k^T / sqrt(d) + mask)
  over all keys, exactly as the eager function does, and keeps the camera's image-token columns.

Prefix layout (lerobot 0.6.1 `VLAFlowMatching.embed_prefix`): for each camera in order, [2 special tokens if
add_image_special_tokens] + its image tokens + [1 special token], then language, then state.

Gradient checkpointing: the probe keeps its own saved tensors (`gazereg.attention.probe.own_saved_tensors`), so
the capture works inside non-reentrant `torch.utils.checkpoint` regions; a layer run without autograd inside a
grad-enabled training forward (reentrant checkpointing) raises a UsageError instead of giving a gaze term with
no gradient. (SmolVLA 0.6.1 itself has no gradient-checkpointing option.)
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor, nn

from gazereg.attention.probe import AttentionProbe, ProbeSpec, require_grad_mode

from .gaze_common import check_gaze_layers


@dataclass
class _State:
    camera_index: int
    layers: tuple[int, ...]
    special: bool
    image_tokens: list[int] = field(default_factory=list)  # tokens per embed_image call, in camera order
    layer: int | None = None
    expert_call: int | None = None  # which eager call of the current layer carries the expert's queries
    suffix_len: int = 0
    calls: int = 0
    probe: AttentionProbe | None = None
    keys: Tensor | None = None
    grad: bool = False  # autograd was on (and the model training) when the capture started


def counting_tokens(embed: Callable[[Tensor], Tensor], counts: list[int]) -> Callable[[Tensor], Tensor]:
    """`embed` (images -> (B, n_tokens, D) image tokens) wrapped to append each call's n_tokens to `counts`:
    the captures learn where each camera's tokens sit in the sequence from these counts."""

    def embed_image(image: Tensor) -> Tensor:
        out = embed(image)
        counts.append(int(out.shape[1]))
        return out

    return embed_image


class CaptureResults:
    """What a capture gives after a captured forward (shared by `SmolVLACapture` and capture_pi0.`PiCapture`):
    `self.state` holds the image tokens of each camera (`image_tokens`, in embedding order) and the
    `AttentionProbe` (`probe`) of the last captured forward; None before the first."""

    state: Any = None

    @property
    def image_tokens(self) -> list[int]:
        """Image tokens of each camera in the last captured forward."""
        return [] if self.state is None else list(self.state.image_tokens)

    def _probe(self) -> AttentionProbe:
        if self.state is None or self.state.probe is None:
            raise RuntimeError("no attention captured: run the policy's forward inside capture() first")
        return self.state.probe

    def attention(self, eps: float = 1e-12) -> Tensor:
        """(B, n_image_tokens) attention of the action tokens to the camera's image tokens, averaged over heads,
        action tokens and layers and renormalised over the camera's tokens (row-major over its token grid)."""
        return self._probe().distribution(eps)

    def raw_attention(self) -> Tensor:
        """(B, n_image_tokens) as `attention()` but NOT renormalised: its row sum is the image mass in [0, 1]."""
        return self._probe().mean_rows()

    def patch_mass(self) -> Tensor:
        """(B,) attention mass the action tokens put on the camera's image tokens, before renormalisation."""
        return self._probe().patch_mass()

    @staticmethod
    def _image_keys(
        counts: list[int], camera: int, n_keys: int, device: torch.device, around: tuple[int, int] = (0, 0)
    ) -> Tensor:
        """(counts[camera],) key positions of the camera's image tokens in a prefix that holds, for each camera
        in order, around[0] tokens + its counts[c] image tokens + around[1] tokens."""
        if camera >= len(counts):
            raise RuntimeError(f"camera {camera} was not embedded: the prefix holds {len(counts)} image(s)")
        before, after = around
        start = sum(before + n + after for n in counts[:camera]) + before
        if start + counts[camera] > n_keys:
            raise RuntimeError(
                f"image tokens {start}..{start + counts[camera]} exceed the {n_keys} attention keys"
            )
        return torch.arange(start, start + counts[camera], device=device)


def _tracking_layers(state: _State, orig: Any, cross: bool) -> Any:
    """`orig` (SmolVLA's forward_attn_layer or forward_cross_attn_layer) wrapped to note in `state` which layer
    runs and which of its eager-attention calls is the action expert's (None: none to capture)."""

    def run(model_layers, inputs_embeds, layer_idx, *args: Any, **kwargs: Any):
        has_expert = len(inputs_embeds) > 1 and inputs_embeds[1] is not None
        has_expert = has_expert and model_layers[1][layer_idx] is not None
        state.layer, state.calls = layer_idx, 0
        state.suffix_len = inputs_embeds[1].shape[1] if has_expert else 0
        if not has_expert or layer_idx not in state.layers:
            state.expert_call = None
        elif cross:
            past = kwargs.get("past_key_values", args[5] if len(args) > 5 else None)
            state.expert_call = 1 if (len(inputs_embeds) == 2 and not past) else 0
        else:
            state.expert_call = 0
        try:
            return orig(model_layers, inputs_embeds, layer_idx, *args, **kwargs)
        finally:
            state.layer = state.expert_call = None

    return run


def expert_layers(n_vlm: int, n_expert: int) -> list[int]:
    """The VLM layer indices (of `n_vlm`) at which SmolVLA's action expert (`n_expert` layers) attends: every
    `n_vlm // n_expert`-th layer, starting at 0 (all of them when the expert has as many layers)."""
    multiple = n_vlm // n_expert
    return [i for i in range(n_vlm) if not (multiple > 0 and i > 0 and i % multiple != 0)]


def expert_layers_text(n_vlm: int, layers: list[int]) -> str:
    """What `--policy.gaze_layers` may name in SmolVLA, for a refusal."""
    return f"the VLM has {n_vlm} layers and the action expert attends at VLM layers {layers}"


class SmolVLACapture(CaptureResults):
    """Capture of `VLAFlowMatching`'s expert-to-image attention on chosen VLM layer indices.

    model: the policy's `VLAFlowMatching` (`policy.model`).
    layers: VLM layer indices (0..num_vlm_layers-1) at which the expert attends; None = the second half of
        the layers that have an expert layer; any other index is refused (GazeUsageError naming gaze_layers).
    """

    def __init__(self, model: nn.Module, layers: list[int] | tuple[int, ...] | None = None):
        self.model = model
        self.vwe = model.vlm_with_expert
        n = self.vwe.num_vlm_layers
        self.expert_layers = expert_layers(n, self.vwe.num_expert_layers)
        if layers is None:
            layers = self.expert_layers[len(self.expert_layers) // 2 :]
        self.layers = tuple(int(i) for i in layers)
        check_gaze_layers(self.layers, self.expert_layers, expert_layers_text(n, self.expert_layers))
        self.state: _State | None = None

    # ----- capture ------------------------------------------------------------------------------------------
    @contextlib.contextmanager
    def capture(self, camera_index: int) -> Iterator[SmolVLACapture]:
        """Capture during the forwards run inside; `camera_index` is the camera's position among the images the
        policy embeds (its order in `config.image_features` among those present in the batch)."""
        vwe = self.vwe
        state = _State(
            camera_index=camera_index,
            layers=self.layers,
            special=bool(self.model.config.add_image_special_tokens),
            grad=torch.is_grad_enabled() and self.model.training,
        )
        self.state = state
        orig_embed = vwe.embed_image
        orig_attn_layer = vwe.forward_attn_layer
        orig_cross_layer = vwe.forward_cross_attn_layer
        orig_eager = vwe.eager_attention_forward

        embed_image = counting_tokens(orig_embed, state.image_tokens)

        def eager(attention_mask, batch_size, head_dim, query_states, key_states, value_states):
            out = orig_eager(attention_mask, batch_size, head_dim, query_states, key_states, value_states)
            call = state.calls
            state.calls += 1
            if state.expert_call is not None and call == state.expert_call:
                require_grad_mode(state.grad, f"SmolVLA layer {state.layer}")
                self._record(state, attention_mask, head_dim, query_states, key_states)
            return out

        vwe.embed_image = embed_image
        vwe.forward_attn_layer = _tracking_layers(state, orig_attn_layer, cross=False)
        vwe.forward_cross_attn_layer = _tracking_layers(state, orig_cross_layer, cross=True)
        vwe.eager_attention_forward = eager
        try:
            yield self
        finally:
            for name in (
                "embed_image",
                "forward_attn_layer",
                "forward_cross_attn_layer",
                "eager_attention_forward",
            ):
                vwe.__dict__.pop(name, None)

    def _record(self, state: _State, mask: Tensor, head_dim: int, q: Tensor, k: Tensor) -> None:
        # q (B, Lq, H, D), k (B, S, Hkv, D), mask (B, Lq, S) bool (True = attend)
        rows = slice(q.shape[1] - state.suffix_len, q.shape[1])
        qh = q[:, rows].transpose(1, 2)
        kh = k.transpose(1, 2)
        m = mask[:, rows][:, None]
        if state.probe is None:
            around = (2, 1) if state.special else (0, 0)
            state.keys = self._image_keys(
                state.image_tokens, state.camera_index, k.shape[1], k.device, around
            )
            state.probe = AttentionProbe(
                None, ProbeSpec(queries=slice(None), keys=state.keys, layers=state.layers)
            )
        state.probe.record(state.layer, qh, kh, m, head_dim**-0.5)
