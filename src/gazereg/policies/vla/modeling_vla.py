"""The reference VLA policy (the paper's Figure 2, scaled to taste by `VLAConfig`), a `Policy`
(gazereg.policies.base) registered as "vla". Its blocks live in layers_vla, its input processing
(tokenizer, normalisation, image resizing, augmentation) in processor_vla.

Token sequence, one transformer over all of it (T = P + K tokens):

    [ camera 0 patches | camera 1 patches | ... | instruction tokens | proprio | action queries ]
      <-------------------------- prefix (P tokens) ---------------------->   <---- K ---->

- Vision: a small conv stem per image (shared across cameras) -> an h x w patch grid (96 px / 12 = 8 x 8),
  plus a learned position embedding per camera and patch. Each token covers exactly its `patch_size`
  square of the input image (up to the 3x3 conv's one-pixel halo), the grid `geometry(camera)` describes.
- Language: an offline tokenizer (processor_vla.Tokenizer) -> token + position embeddings; padding keys are
  masked out.
- Proprioception: one token, a linear map of the normalised state.
- Action queries: K tokens (a chunk of K future actions). L1 head: learned query embeddings; flow head:
  embeddings of the noisy actions plus a flow-time embedding.
- Block attention mask (pi0-style): the prefix attends bidirectionally to itself (never to the actions);
  action query i attends to the whole prefix and causally to action queries 0..i.
- Decoder: LayerNorm + Linear to the action dimension: normalised actions (L1 head, loss L1) or a velocity
  field (flow head, loss MSE to noise - action; Euler integration from t=1 to 0 at inference).

Attention (layers_vla.Attention, explicit softmax or `F.scaled_dot_product_attention`: `VLAConfig.attention`) calls `gazereg.attention.tap(layer, q, k, mask)`: the
gaze regularizer reads the action queries' attention to one camera's patches through an `AttentionProbe`
(`gaze_probe_spec`) without changing the forward; with `--gaze.queries language` (or `both`) the instruction's
real tokens' attention to the patches instead (or as well), padding tokens left out by per-sample weights. Inference (`select_action`) never sees gaze.

Shapes: B batch, T tokens, D width, H heads, N = patches per camera, L text tokens, K chunk, S state dim,
A action dim. Images enter as stored uint8 frames (B, H_img, W_img, 3).
"""

from __future__ import annotations

import dataclasses
import logging
from collections import deque
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from gazereg.attention.probe import ProbeSpec, QuerySet
from gazereg.data.dataset import StoreInfo
from gazereg.patches import PatchGeometry
from gazereg.policies.base import Policy, UnknownCamera
from gazereg.policies.vla.configuration_vla import VLAConfig
from gazereg.policies.vla.layers_vla import Block, ConvStem, attention_bias, flow_time_embedding
from gazereg.policies.vla.processor_vla import Normalizer, Tokenizer, random_shift, to_input_images
from gazereg.runtime.errors import UsageError

log = logging.getLogger(__name__)


class VLAPolicy(Policy):
    """The reference vision-language-action policy. See the module docstring for the architecture."""

    config_class = VLAConfig
    gaze_query_sets = frozenset(QuerySet)
    config: VLAConfig
    tokenizer: Tokenizer

    def __init__(self, config: VLAConfig, tokenizer: Tokenizer):
        super().__init__(config, tokenizer)
        if tokenizer.vocab_size != config.vocab_size or tokenizer.max_len != config.max_text_len:
            raise ValueError(
                f"tokenizer (vocab {tokenizer.vocab_size}, max_len {tokenizer.max_len}) does not match the config "
                f"(vocab_size {config.vocab_size}, max_text_len {config.max_text_len})"
            )
        D, N, K = config.dim, config.n_patches, config.chunk
        n_cams = len(config.cameras)
        self.normalizer = Normalizer(config.state_dim, config.action_dim, config.norm_eps)
        self.stem = ConvStem(config)
        self.image_pos = nn.Parameter(torch.zeros(n_cams, N, D))
        self.text_embed = nn.Embedding(config.vocab_size, D)
        self.text_pos = nn.Parameter(torch.zeros(config.max_text_len, D))
        self.state_proj = nn.Linear(config.state_dim, D)
        self.action_pos = nn.Parameter(torch.zeros(K, D))
        if config.head == "flow":
            self.action_in = nn.Linear(config.action_dim, D)
            self.time_mlp = nn.Sequential(nn.Linear(D, D), nn.GELU(), nn.Linear(D, D))
        self.blocks = nn.ModuleList(Block(config, i) for i in range(config.depth))
        self.norm = nn.LayerNorm(D)
        self.action_out = nn.Linear(D, config.action_dim)
        self.apply(self._init)
        for p in (self.image_pos, self.text_pos, self.action_pos):
            nn.init.trunc_normal_(p, std=0.02)
        # token layout
        self.n_image_tokens = n_cams * N
        self.n_prefix = self.n_image_tokens + config.max_text_len + 1
        self.n_tokens = self.n_prefix + K
        self.reset()

    @staticmethod
    def _init(m: nn.Module) -> None:
        if isinstance(m, nn.Linear | nn.Embedding):
            nn.init.trunc_normal_(m.weight, std=0.02)
            if getattr(m, "bias", None) is not None:
                nn.init.zeros_(m.bias)

    @classmethod
    def from_data(cls, config: VLAConfig, data: StoreInfo) -> VLAPolicy:  # type: ignore[override]
        """Tokenizer from the training instructions, config resolved from the data and the vocabulary."""
        tok = Tokenizer.build(data.instructions, config.tokenizer, config.max_text_len)
        return cls(dataclasses.replace(config.resolve(data), vocab_size=tok.vocab_size), tok)

    @classmethod
    def load_tokenizer(cls, path: Path) -> Tokenizer:
        return Tokenizer.load(path)

    def set_normalization(self, state_mean: Any, state_std: Any, action_mean: Any, action_std: Any) -> None:
        self.normalizer.set_stats(state_mean, state_std, action_mean, action_std)

    # ----- geometry and the gaze probe ---------------------------------------------------------------------
    def camera_index(self, camera: str) -> int:
        if camera not in self.config.cameras:
            raise UnknownCamera(
                f"camera {camera!r} is not one of the policy's cameras ({', '.join(self.config.cameras)})"
            )
        return self.config.cameras.index(camera)

    def geometry(self, camera: str) -> PatchGeometry:
        """The image geometry of `camera` as this policy sees it: stored frame -> input image -> patch grid."""
        c = self.config
        geo = PatchGeometry(
            input_hw=tuple(c.image_hw),
            patch_size=c.patch_size,
            src_hw=tuple(c.camera_hw[self.camera_index(camera)]),
            resize="stretch",
            orientation=c.orientation,
        )
        geo.check_grid(c.grid_hw)
        return geo

    def patch_positions(self, camera: str) -> slice:
        """Token positions of `camera`'s patch tokens (row-major over its grid)."""
        i, N = self.camera_index(camera), self.config.n_patches
        return slice(i * N, (i + 1) * N)

    def action_positions(self) -> slice:
        return slice(self.n_prefix, self.n_tokens)

    def resolve_layers(self, layers: Sequence[int] | None) -> tuple[int, ...]:
        depth = self.config.depth
        layers = (depth - 2, depth - 1) if layers is None else tuple(layers)
        out = tuple(sorted({lay % depth if -depth <= lay < depth else lay for lay in layers}))
        bad = [lay for lay in out if not 0 <= lay < depth]
        if bad or not out:
            raise ValueError(f"attention layers {list(layers)} out of range for a {depth}-layer policy")
        return out

    def text_positions(self) -> slice:
        """Token positions of the L instruction tokens (padding included)."""
        return slice(self.n_image_tokens, self.n_image_tokens + self.config.max_text_len)

    def gaze_probe_spec(
        self,
        camera: str,
        layers: Sequence[int] | None = None,
        queries: QuerySet = QuerySet.ACTION,
        text_mask: Tensor | None = None,
    ) -> ProbeSpec:
        """Keys: `camera`'s N patch positions; layers: default the last 2 (negative ids count from the end).
        Queries: ACTION the K action query positions (no weights: today's plain mean); LANGUAGE the L text
        positions with weights `text_mask` (B, L) (1 real token, 0 padding; the prefix attends bidirectionally,
        so every text token sees the patches); BOTH the L text positions then the K action positions, weights
        [text_mask | 1] (B, L + K): every valid row counts equally. LANGUAGE and BOTH need `text_mask`;
        LANGUAGE refuses (UsageError) a sample without a real token (an empty instruction)."""
        keys, layers = self.patch_positions(camera), self.resolve_layers(layers)
        queries = QuerySet(queries)
        if queries is QuerySet.ACTION:
            return ProbeSpec(queries=self.action_positions(), keys=keys, layers=layers)
        L = self.config.max_text_len
        if text_mask is None or text_mask.ndim != 2 or text_mask.shape[1] != L:
            raise ValueError(f"{queries.value} queries need the batch's text_mask (B, {L}) bool")
        if queries is QuerySet.LANGUAGE and (empty := int((~text_mask.bool().any(1)).sum())):
            raise UsageError(
                f"language queries need a real instruction token in every sample: {empty} of "
                f"{text_mask.shape[0]} sample(s) have an empty instruction"
            )
        weights = text_mask.float()
        if queries is QuerySet.LANGUAGE:
            return ProbeSpec(queries=self.text_positions(), keys=keys, layers=layers, query_weights=weights)
        pos = torch.arange(self.n_tokens)
        positions = torch.cat([pos[self.text_positions()], pos[self.action_positions()]])
        weights = torch.cat([weights, weights.new_ones(weights.shape[0], self.config.chunk)], 1)
        return ProbeSpec(queries=positions, keys=keys, layers=layers, query_weights=weights)

    def layer_module(self, layer: int) -> nn.Module:
        """Block `layer`: its output's first element is every token's features (B, T, D) after the layer."""
        return self.blocks[self.resolve_layers((layer,))[0]]

    # ----- forward -----------------------------------------------------------------------------------------
    def attention_mask(self, text_mask: Tensor) -> Tensor:
        """Block mask (B, 1, T, T) bool, True = query (row) may attend to key (column)."""
        B, dev = text_mask.shape[0], text_mask.device
        P, T, n_img = self.n_prefix, self.n_tokens, self.n_image_tokens
        idx = torch.arange(T, device=dev)
        allowed = (idx[None, :] < P) | ((idx[:, None] >= P) & (idx[None, :] <= idx[:, None]))  # (T, T)
        key_ok = torch.ones(B, T, dtype=torch.bool, device=dev)
        key_ok[:, n_img : n_img + text_mask.shape[1]] = text_mask
        return (allowed[None] & key_ok[:, None, :])[:, None]

    def encode_images(
        self, batch: Mapping[str, Tensor], shift: int = 0, generator: torch.Generator | None = None
    ) -> Tensor:
        """Every camera's stored frames batch['image.<cam>'] -> patch tokens (B, n_cams * N, D)."""
        c = self.config
        missing = [cam for cam in c.cameras if f"image.{cam}" not in batch]
        if missing:
            raise KeyError(
                f"batch has no frames for camera(s) {missing} (keys image.<camera>); it has {sorted(batch)}"
            )
        imgs = [
            to_input_images(batch[f"image.{cam}"].to(self.device), c.image_hw, c.orientation)
            for cam in c.cameras
        ]
        x = torch.cat(imgs)  # (n_cams * B, 3, H, W)
        if shift > 0:
            if generator is None:
                raise ValueError("random shift augmentation needs an explicit torch.Generator")
            x = random_shift(x, shift, generator)
        tok = self.stem(
            x.contiguous(memory_format=torch.channels_last)
        )  # (n_cams * B, N, D); NHWC convs are faster
        B = tok.shape[0] // len(c.cameras)
        tok = tok.reshape(len(c.cameras), B, c.n_patches, c.dim) + self.image_pos[:, None]
        return tok.transpose(0, 1).reshape(B, -1, c.dim)

    def prefix_tokens(
        self, batch: Mapping[str, Tensor], shift: int = 0, generator: torch.Generator | None = None
    ) -> Tensor:
        img = self.encode_images(batch, shift, generator)
        text = self.text_embed(batch["text_ids"].to(self.device)) + self.text_pos
        state = self.state_proj(self.normalizer.state(batch["state"].to(self.device).float()))[:, None]
        return torch.cat([img, text, state], 1)

    def action_tokens(self, B: int, noisy: Tensor | None = None, t: Tensor | None = None) -> Tensor:
        if self.config.head == "l1":
            return self.action_pos[None].expand(B, -1, -1)
        assert noisy is not None and t is not None
        temb = self.time_mlp(flow_time_embedding(t, self.config.dim))
        return self.action_in(noisy) + temb[:, None] + self.action_pos

    def run_transformer(
        self, prefix: Tensor, actions: Tensor, mask: Tensor, output_attentions: bool = False
    ) -> tuple[Tensor, list[Tensor]]:
        """Returns the decoded action-query outputs (B, K, A) and, if asked, every layer's (B, H, T, T) probs."""
        x = torch.cat([prefix, actions], 1)
        bias = attention_bias(mask)
        attentions = []
        for blk in self.blocks:
            x, probs = blk(x, mask, output_attentions, bias)
            if probs is not None:
                attentions.append(probs)
        return self.action_out(self.norm(x[:, self.n_prefix :])), attentions

    def forward(
        self,
        batch: Mapping[str, Tensor],
        generator: torch.Generator | None = None,
        shift: int = 0,
        output_attentions: bool = False,
    ) -> tuple[Tensor, dict[str, Any]]:
        """Training loss. batch: image.<cam> uint8 (B, H, W, 3), state (B, S), action (B, K, A) raw,
        action_pad (B, K) bool (True = past the episode end, excluded), text_ids (B, L), text_mask (B, L).
        `generator` drives every random draw (shift augmentation, flow noise and times).
        Returns (loss, info) with info['loss/action'] a float (and info['attentions'] if asked)."""
        prefix = self.prefix_tokens(batch, shift, generator)
        B, dev = prefix.shape[0], prefix.device
        target = self.normalizer.action(batch["action"].to(dev).float())
        keep = (
            (~batch["action_pad"].to(dev)).float()[..., None]
            if "action_pad" in batch
            else torch.ones_like(target[..., :1])
        )
        mask = self.attention_mask(batch["text_mask"].to(dev))
        if self.config.head == "l1":
            pred, attn = self.run_transformer(prefix, self.action_tokens(B), mask, output_attentions)
            err = (pred - target).abs()
        else:
            if generator is None:
                raise ValueError(
                    "the flow head samples noise and times during training: pass a torch.Generator"
                )
            noise = torch.randn(target.shape, generator=generator, device=generator.device).to(dev)
            t = torch.rand(B, generator=generator, device=generator.device).to(dev)
            x_t = t[:, None, None] * noise + (1 - t[:, None, None]) * target
            pred, attn = self.run_transformer(prefix, self.action_tokens(B, x_t, t), mask, output_attentions)
            err = (pred - (noise - target)).pow(2)
        loss = (err * keep).sum() / (keep.sum() * err.shape[-1]).clamp_min(1.0)
        info: dict[str, Any] = {"loss/action": float(loss.detach())}
        if output_attentions:
            info["attentions"] = attn
        return loss, info

    @torch.no_grad()
    def predict_action_chunk(
        self, batch: Mapping[str, Tensor], generator: torch.Generator | None = None
    ) -> Tensor:
        """(B, K, A) unnormalised actions for a prepared batch (no gaze, no action inputs needed)."""
        prefix = self.prefix_tokens(batch)
        B, dev = prefix.shape[0], prefix.device
        mask = self.attention_mask(batch["text_mask"].to(dev))
        if self.config.head == "l1":
            pred, _ = self.run_transformer(prefix, self.action_tokens(B), mask)
        else:
            shape = (B, self.config.chunk, self.config.action_dim)
            gen_dev = generator.device if generator is not None else dev
            x = torch.randn(shape, generator=generator, device=gen_dev).to(dev)
            n = self.config.flow_steps
            for i in range(n):
                t = torch.full((B,), 1.0 - i / n, device=dev)
                v, _ = self.run_transformer(prefix, self.action_tokens(B, x, t), mask)
                x = x - v / n
            pred = x
        return self.normalizer.unaction(pred)

    # ----- inference ---------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget queued actions and ensembling history (call at every episode start)."""
        self._queue: deque[Tensor] = deque()
        self._history: deque[Tensor] = deque(maxlen=self.config.chunk)
        self._text_cache: dict[tuple[str, ...], tuple[Tensor, Tensor]] = {}

    def make_batch(
        self, observation: Mapping[str, Any], instruction: str | Sequence[str]
    ) -> tuple[dict[str, Tensor], bool]:
        """Observation {'state': (S,) | (B, S), '<camera>' or 'image.<camera>': uint8 (H, W, 3) | (B, H, W, 3)}
        (or {'images': {camera: frames}}) + instruction(s) -> (batch, was_batched)."""
        images = observation.get("images", {})
        batch: dict[str, Tensor] = {}
        if "state" not in observation:
            raise KeyError(f"observation needs 'state'; it has {sorted(observation)}")
        state = torch.as_tensor(np.asarray(observation["state"], dtype=np.float32))
        batched = state.ndim == 2
        batch["state"] = state if batched else state[None]
        if batch["state"].shape[-1] != self.config.state_dim:
            raise ValueError(
                f"state has {batch['state'].shape[-1]} values, the policy expects {self.config.state_dim}"
            )
        for cam in self.config.cameras:
            frame = images.get(cam, observation.get(f"image.{cam}", observation.get(cam)))
            if frame is None:
                raise KeyError(f"observation has no frame for camera {cam!r}; keys: {sorted(observation)}")
            fr = torch.as_tensor(np.ascontiguousarray(frame)) if not isinstance(frame, Tensor) else frame
            batch[f"image.{cam}"] = fr if batched else fr[None]
        B = batch["state"].shape[0]
        texts = (instruction,) * B if isinstance(instruction, str) else tuple(instruction)
        if len(texts) != B:
            raise ValueError(f"{len(texts)} instructions for a batch of {B} observations")
        if texts not in self._text_cache:
            unknown = sorted({w for t in texts for w in self.tokenizer.unknown_words(t)})
            if unknown:
                log.warning(
                    "instruction words unknown to the policy's vocabulary (mapped to <unk>): %s", unknown
                )
            self._text_cache[texts] = self.tokenizer(list(texts))
        batch["text_ids"], batch["text_mask"] = self._text_cache[texts]
        return batch, batched

    @torch.no_grad()
    def select_action(
        self,
        observation: Mapping[str, Any],
        instruction: str | Sequence[str],
        generator: torch.Generator | None = None,
    ) -> np.ndarray:
        """The next action (A,) (or (B, A) for batched observations) as float32 numpy.

        Receding horizon: a chunk is predicted when the queue is empty and its first `n_action_steps` actions
        are executed in turn. With `temporal_ensemble` set, a chunk is predicted every step and the current
        action is the exp(-coef * i)-weighted mean of every stored chunk's prediction for now (i = 0 oldest)."""
        was_training = self.training
        self.eval()
        try:
            batch, batched = self.make_batch(observation, instruction)
            coef = self.config.temporal_ensemble
            if coef is not None:
                self._history.append(self.predict_action_chunk(batch, generator))  # newest last
                n = len(self._history)
                preds = torch.stack(
                    [c[:, n - 1 - j] for j, c in enumerate(self._history)]
                )  # oldest first (n, B, A)
                w = torch.exp(-coef * torch.arange(n, dtype=preds.dtype, device=preds.device))
                action = (w[:, None, None] * preds).sum(0) / w.sum()
            else:
                if not self._queue:
                    chunk = self.predict_action_chunk(batch, generator)
                    self._queue.extend(chunk[:, i] for i in range(self.config.n_action_steps))
                action = self._queue.popleft()
        finally:
            self.train(was_training)
        out = action.float().cpu().numpy()
        return out if batched else out[0]
