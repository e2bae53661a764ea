"""Differentiable capture of pi0 / pi0.5's action-expert attention to one camera's image tokens.

In training, lerobot's `PaliGemmaWithExpertModel` runs every layer jointly (`compute_layer_complete`): the prefix
(images, language) and the expert's suffix (pi0: state + action tokens; pi0.5: action tokens) share one attention,
computed by `transformers.models.gemma.modeling_gemma.eager_attention_forward`, looked up on that module at each
call. Inside `PiCapture.capture()` two things are wrapped (both restored on exit; nothing is copied):

- the model's `embed_image` (instance attribute): counts the image tokens of each camera (prefix layout);
- `modeling_gemma.eager_attention_forward` (module attribute): runs the original (outputs bit-identical), numbers
  the call as the layer index, and hands the last `n_queries` query rows (the action tokens), the keys and the
  additive mask to a `gazereg.attention.AttentionProbe`, which recomputes softmax(q k^T * scaling + mask) exactly
  as the eager function does and keeps the camera's image-token columns.

Prefix layout (lerobot 0.6.1 `PI0Pytorch.embed_prefix` / `PI05Pytorch.embed_prefix`): the image tokens of each
camera in order (present cameras, then the padded missing ones), no special tokens, then the language tokens.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from torch import Tensor, nn
from transformers.models.gemma import modeling_gemma

from gazereg.attention.probe import AttentionProbe, ProbeSpec

from .capture import CaptureResults, counting_tokens
from .gaze_common import check_gaze_layers


def depth_text(depth: int) -> str:
    """What `--policy.gaze_layers` may name in pi0 / pi0.5 (every layer is joint), for a refusal."""
    return f"the model has {depth} layers, 0..{depth - 1}"


@dataclass
class _State:
    camera_index: int
    n_queries: int
    layers: tuple[int, ...]
    image_tokens: list[int] = field(default_factory=list)  # tokens per embed_image call, in camera order
    calls: int = 0  # eager attention calls so far = the index of the next layer
    probe: AttentionProbe | None = None
    keys: Tensor | None = None


class PiCapture(CaptureResults):
    """Capture of a `PI0Pytorch` / `PI05Pytorch` model's action-token attention to one camera's image tokens.

    model: the policy's core model (`policy.model`).
    layers: layer indices (0..depth-1); None = the second half of the layers; any other index is refused
        (GazeUsageError naming gaze_layers).
    """

    def __init__(self, model: nn.Module, layers: list[int] | tuple[int, ...] | None = None):
        self.model = model
        self.pwe = model.paligemma_with_expert
        self.depth = len(self.pwe.paligemma.model.language_model.layers)
        if layers is None:
            layers = range(self.depth // 2, self.depth)
        self.layers = tuple(int(i) for i in layers)
        check_gaze_layers(self.layers, range(self.depth), depth_text(self.depth))
        self.state: _State | None = None

    # ----- capture ------------------------------------------------------------------------------------------
    @contextlib.contextmanager
    def capture(self, camera_index: int, n_queries: int) -> Iterator[PiCapture]:
        """Capture during the training forward run inside. `camera_index`: the camera's position among the
        images the policy embeds (its order in `config.image_features` among those present in the batch);
        `n_queries`: the action tokens at the end of the sequence (`config.chunk_size`)."""
        state = _State(camera_index=camera_index, n_queries=n_queries, layers=self.layers)
        self.state = state
        pwe = self.pwe
        orig_embed = pwe.embed_image
        orig_eager = modeling_gemma.eager_attention_forward

        embed_image = counting_tokens(orig_embed, state.image_tokens)

        def eager(module, query, key, value, attention_mask, scaling, *args: Any, **kwargs: Any):
            out = orig_eager(module, query, key, value, attention_mask, scaling, *args, **kwargs)
            layer = state.calls
            state.calls += 1
            if layer in state.layers:
                self._record(state, layer, query, key, attention_mask, scaling)
            return out

        pwe.embed_image = embed_image
        modeling_gemma.eager_attention_forward = eager
        try:
            yield self
        finally:
            modeling_gemma.eager_attention_forward = orig_eager
            pwe.__dict__.pop("embed_image", None)
        if state.calls != self.depth:
            raise RuntimeError(
                f"the forward ran {state.calls} eager attention calls, expected one per layer ({self.depth}): "
                "this lerobot version's pi0 forward differs from the one the capture was written for"
            )

    def _record(
        self, state: _State, layer: int, q: Tensor, k: Tensor, mask: Tensor | None, scaling: float
    ) -> None:
        # q (B, H, L, D) after rotary, k (B, Hkv, S, D), mask (B, 1, L, S) additive float
        if state.probe is None:
            state.keys = self._image_keys(state.image_tokens, state.camera_index, k.shape[2], k.device)
            rows = slice(q.shape[2] - state.n_queries, q.shape[2])
            state.probe = AttentionProbe(None, ProbeSpec(queries=rows, keys=state.keys, layers=state.layers))
        state.probe.record(layer, q, k, mask, scaling)
