"""The attention probe: capture differentiable attention probabilities during a training forward pass.

Model code that computes attention calls `tap(layer, q, k, mask, scale)` with its query and key tensors;
when no probe is active this is a single context-variable lookup. Inside `with AttentionProbe(...)`, the probe
recomputes softmax(q k^T * scale + mask) for the selected layers and query rows only (over all keys, so the
probabilities are exactly the model's), keeps the columns of the selected keys (one camera's patches),
and `distribution()` reduces them over heads, queries and layers and renormalises over those keys. Which
tokens are the queries is a policy's choice named by a `QuerySet` (the action queries, the instruction's
tokens, or both); per-sample query weights (`ProbeSpec.query_weights`) leave out rows such as padding tokens.

The forward itself is untouched: the model keeps its fused attention kernel, and its outputs are
bit-identical with and without the probe. Models whose attention code cannot call `tap` plug in through
adapters (`attach(model, probe) -> handles`), installed on entry and removed on exit; this module ships one
for `torch.nn.MultiheadAttention`.
"""

from __future__ import annotations

import contextlib
import contextvars
import enum
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from gazereg.runtime.errors import UsageError

_ACTIVE: contextvars.ContextVar[AttentionProbe | None] = contextvars.ContextVar("gazereg_probe", default=None)

Index = slice | Sequence[int] | Tensor


class QuerySet(str, enum.Enum):
    """Whose attention the gaze term reads (`--gaze.queries`): the action queries (the default), the
    instruction's language tokens (padding excluded), or both (every query row weighted equally)."""

    ACTION = "action"
    LANGUAGE = "language"
    BOTH = "both"


QUERY_SETS: tuple[str, ...] = tuple(q.value for q in QuerySet)
"""the `--gaze.queries` values, in QuerySet order"""


@dataclass(frozen=True)
class ProbeSpec:
    """Which attention to capture.

    layers: layer ids as the model (or adapter) numbers them; None captures every tapped layer.
    queries: query positions (the tokens whose attention is regularized, e.g. the action queries).
    keys: key positions of one camera's patch tokens, row-major over its patch grid: a slice, a list,
        a (n_keys,) tensor, or a (B, n_keys) tensor when positions differ per sample.
    reduce: how heads, queries and layers are combined before renormalising over the keys.
    query_weights: None (every query row counts equally: a plain mean) or (B, n_queries) non-negative
        weights aligned with `queries`, e.g. 1 for an instruction's real tokens and 0 for its padding; the
        mean over query rows is then the weighted mean, per sample. Every sample needs a positive weight.
    """

    queries: Index
    keys: Index
    layers: tuple[int, ...] | None = None
    reduce: Literal["mean"] = "mean"
    query_weights: Tensor | None = None


def _positions(index: Index, length: int, device: torch.device) -> Tensor:
    if isinstance(index, slice):
        return torch.arange(length, device=device)[index]
    t = torch.as_tensor(index, dtype=torch.long, device=device)
    if t.numel() and (t.min() < 0 or t.max() >= length):
        raise IndexError(
            f"token positions {t.min().item()}..{t.max().item()} out of range for {length} tokens"
        )
    return t


def attention_rows(
    q: Tensor, k: Tensor, queries: Index, mask: Tensor | None = None, scale: float | None = None
) -> Tensor:
    """softmax(q[..., queries, :] k^T * scale + mask) for the selected query rows.

    q: (B, H, Tq, d), k: (B, Hk, Tk, d) with H a multiple of Hk (grouped-query attention);
    mask: broadcastable to (B, H, Tq, Tk), bool (True = may attend) or additive float.
    Returns (B, H, n_queries, Tk) float32 probabilities.
    """
    B, H, Tq, d = q.shape
    if k.shape[1] != H:
        k = k.repeat_interleave(H // k.shape[1], dim=1)
    qi = _positions(queries, Tq, q.device)
    scale = 1.0 / math.sqrt(d) if scale is None else scale
    with torch.autocast(q.device.type, enabled=False):  # float32 even inside a bf16/fp16 autocast region
        logits = torch.matmul(q[:, :, qi].float(), k.float().transpose(-1, -2)) * scale
    if mask is not None:
        m = mask[..., qi, :] if mask.shape[-2] == Tq else mask  # a (.., 1, Tk) mask broadcasts over rows
        logits = logits.masked_fill(~m, float("-inf")) if m.dtype == torch.bool else logits + m.float()
    return torch.softmax(logits, dim=-1)


def _pack(t: Tensor) -> Tensor:
    """A saved tensor as a detached alias (same storage, no autograd history): returning `t` itself would tie a
    saved output to the node that saves it, a reference cycle that only backward breaks, so a capture whose
    attention never reaches a loss (the location control logs it detached) kept every step's graph alive."""
    return t.detach()


def _unpack(t: Tensor) -> Tensor:
    return t


def own_saved_tensors() -> contextlib.AbstractContextManager[None]:
    """Inside, tensors saved for backward are kept as they are, not handed to an enclosing saved-tensor hook.

    The probe's extra ops (gather, q k^T, softmax) run inside the model's layers; under non-reentrant gradient
    checkpointing (`torch.utils.checkpoint(use_reentrant=False)`, transformers' default) the checkpoint's hook
    would count their saved tensors and find fewer on recomputation (the capture is not repeated in backward),
    failing with CheckpointError. Kept outside the checkpoint, they cost a little memory on the probed layers
    only, and their gradient still reaches q and k through the recomputed region."""
    return torch.autograd.graph.saved_tensors_hooks(_pack, _unpack)


def require_grad_mode(expect_grad: bool, where: str) -> None:
    """Raise when the capture expects a gradient but runs with autograd off: reentrant gradient checkpointing
    (`use_reentrant=True`) runs the checkpointed layers under no_grad, so the captured attention would have no
    gradient and the gaze term would be logged but never optimised."""
    if expect_grad and not torch.is_grad_enabled():
        raise UsageError(
            f"gaze capture in {where} ran without autograd inside a grad-enabled forward: reentrant gradient "
            "checkpointing (use_reentrant=True) gives the gaze term no gradient; use non-reentrant checkpointing, "
            "e.g. model.gradient_checkpointing_enable(gradient_checkpointing_kwargs={'use_reentrant': False})"
        )


def tap(layer: int, q: Tensor, k: Tensor, mask: Tensor | None = None, scale: float | None = None) -> None:
    """Called by attention code with its (B, H, Tq, d) queries and (B, Hk, Tk, d) keys; free when no probe."""
    probe = _ACTIVE.get()
    if probe is not None:
        probe.record(layer, q, k, mask, scale)


class AttentionProbe:
    """Context manager collecting attention from `spec.queries` to `spec.keys` on `spec.layers`.

    with AttentionProbe(model, spec) as probe:
        out = model(batch)
    attn = probe.distribution()   # (B, n_keys), rows sum to 1, differentiable
    """

    def __init__(
        self, model: nn.Module | None, spec: ProbeSpec, adapter: str | Callable[..., list[Any]] = "auto"
    ):
        self.model = model
        self.spec = spec
        self.adapter = adapter
        self._rows: dict[int, Tensor] = {}  # layer -> (B, H, nq, n_keys)
        self._patch_mass: dict[int, Tensor] = {}  # layer -> (B,) attention mass on the keys before renorm
        self._handles: list[Any] = []
        self._token: contextvars.Token | None = None

    # ----- lifecycle ------------------------------------------------------------------------------------
    def __enter__(self) -> AttentionProbe:
        if self._token is not None:
            raise RuntimeError("this AttentionProbe is already active")
        self._rows.clear()
        self._patch_mass.clear()
        self._token = _ACTIVE.set(self)
        attach = self._resolve_adapter()
        if attach is not None and self.model is not None:
            self._handles = list(attach(self.model, self))
        return self

    def __exit__(self, *exc: object) -> None:
        for h in self._handles:
            h.remove()
        self._handles = []
        if self._token is not None:
            _ACTIVE.reset(self._token)
            self._token = None

    def _resolve_adapter(self) -> Callable[..., list[Any]] | None:
        if callable(self.adapter):
            return self.adapter
        if self.adapter == "tap":
            return None
        if self.adapter == "mha":
            return attach_multihead_attention
        if self.adapter != "auto":
            raise ValueError(
                f"unknown probe adapter {self.adapter!r}; use 'auto', 'tap', 'mha' or a callable"
            )
        custom = getattr(self.model, "gaze_probe_adapter", None)
        if callable(custom):
            return custom()
        if self.model is not None and any(isinstance(m, nn.MultiheadAttention) for m in self.model.modules()):
            return attach_multihead_attention
        return None

    # ----- capture --------------------------------------------------------------------------------------
    def wants(self, layer: int) -> bool:
        return self.spec.layers is None or layer in self.spec.layers

    def record(
        self, layer: int, q: Tensor, k: Tensor, mask: Tensor | None = None, scale: float | None = None
    ) -> None:
        if not self.wants(layer):
            return
        with own_saved_tensors():
            self._record(layer, q, k, mask, scale)

    def _record(self, layer: int, q: Tensor, k: Tensor, mask: Tensor | None, scale: float | None) -> None:
        probs = attention_rows(q, k, self.spec.queries, mask, scale)  # (B, H, nq, Tk)
        keys = self.spec.keys
        if isinstance(keys, Tensor) and keys.ndim == 2:
            if keys.shape[0] != probs.shape[0]:
                raise ValueError(
                    f"per-sample key positions have batch {keys.shape[0]}, attention has {probs.shape[0]}"
                )
            idx = keys.to(probs.device)[:, None, None, :].expand(-1, probs.shape[1], probs.shape[2], -1)
            sel = torch.gather(probs, -1, idx)
        else:
            sel = probs[..., _positions(keys, probs.shape[-1], probs.device)]
        self._rows[layer] = sel
        self._patch_mass[layer] = self._mean_queries(sel.sum(-1)).detach()

    def _mean_queries(self, x: Tensor) -> Tensor:
        """(B, H, n_queries, *rest) -> (B, *rest): the mean over heads, then over query rows, weighted by
        `spec.query_weights` when given (None: the plain mean over heads and rows)."""
        w = self.spec.query_weights
        if w is None:
            return x.mean(dim=(1, 2))
        if w.shape != (x.shape[0], x.shape[2]):
            raise ValueError(
                f"query weights have shape {tuple(w.shape)}, the attention has batch {x.shape[0]} and "
                f"{x.shape[2]} query rows"
            )
        w = w.to(device=x.device, dtype=x.dtype)
        w = (w / w.sum(1, keepdim=True)).reshape(*w.shape, *(1,) * (x.ndim - 3))
        return (x.mean(1) * w).sum(1)

    @property
    def layers(self) -> list[int]:
        return sorted(self._rows)

    def rows(self, layer: int) -> Tensor:
        """(B, H, n_queries, n_keys) probabilities captured on one layer (not renormalised)."""
        return self._rows[layer]

    def patch_mass(self) -> Tensor:
        """(B,) mean attention mass the queries put on the selected keys (before renormalisation; weighted
        like `mean_rows`)."""
        self._require()
        return torch.stack([self._patch_mass[i] for i in self.layers]).mean(0)

    def _require(self) -> None:
        if not self._rows:
            want = "any layer" if self.spec.layers is None else f"layers {list(self.spec.layers)}"
            raise RuntimeError(
                f"the attention probe captured nothing for {want}: the model's attention did not call "
                "gazereg.attention.tap and no adapter matched (or the selected layers do not exist)"
            )
        if self.spec.layers is not None:
            missing = sorted(set(self.spec.layers) - set(self._rows))
            if missing:
                raise RuntimeError(
                    f"the attention probe saw no attention on layer(s) {missing}; saw {self.layers}"
                )

    def mean_rows(self) -> Tensor:
        """(B, n_keys): attention averaged over heads, queries (weighted by `spec.query_weights` when given)
        and layers, NOT renormalised (its row sum is the mass on the keys, in [0, 1] for distinct keys);
        differentiable."""
        self._require()
        return torch.stack([self._mean_queries(self._rows[i]) for i in self.layers]).mean(0)

    def distribution(self, eps: float = 1e-12) -> Tensor:
        """(B, n_keys): attention averaged over heads, queries and layers, renormalised over the keys."""
        mean = self.mean_rows()
        return mean / mean.sum(-1, keepdim=True).clamp_min(eps)


# ----- adapter for plain PyTorch attention ---------------------------------------------------------------
def _mha_qk(m: nn.MultiheadAttention, query: Tensor, key: Tensor) -> tuple[Tensor, Tensor]:
    """Recompute the projected (B, H, T, d) queries and keys of an nn.MultiheadAttention call."""
    if m.batch_first:
        query, key = query.transpose(0, 1), key.transpose(0, 1)  # -> (T, B, E)
    E = m.embed_dim
    if m._qkv_same_embed_dim:
        wq, wk = m.in_proj_weight[:E], m.in_proj_weight[E : 2 * E]
    else:
        wq, wk = m.q_proj_weight, m.k_proj_weight
    bq, bk = (m.in_proj_bias[:E], m.in_proj_bias[E : 2 * E]) if m.in_proj_bias is not None else (None, None)
    q, k = F.linear(query, wq, bq), F.linear(key, wk, bk)
    if m.bias_k is not None:
        k = torch.cat([k, m.bias_k.expand(1, k.shape[1], -1)])
    H = m.num_heads

    def heads(x: Tensor) -> Tensor:
        T, B, _ = x.shape
        return x.reshape(T, B, H, E // H).permute(1, 2, 0, 3)

    return heads(q), heads(k)


def _mha_mask(attn_mask: Tensor | None, key_padding_mask: Tensor | None, B: int, H: int) -> Tensor | None:
    """Combine nn.MultiheadAttention masks into one additive (B, H, Tq, Tk) mask (True in torch's bool masks
    means 'not allowed')."""
    out = None
    if attn_mask is not None:
        m = (
            attn_mask
            if attn_mask.dtype != torch.bool
            else torch.zeros_like(attn_mask, dtype=torch.float32).masked_fill(attn_mask, float("-inf"))
        )
        out = m.reshape(B, H, *m.shape[-2:]) if m.ndim == 3 else m[None, None]
    if key_padding_mask is not None:
        kp = key_padding_mask
        kp = (
            torch.zeros_like(kp, dtype=torch.float32).masked_fill(kp, float("-inf"))
            if kp.dtype == torch.bool
            else kp.float()
        )
        kp = kp[:, None, None, :]
        out = kp if out is None else out + kp
    return out


def attach_multihead_attention(model: nn.Module, probe: AttentionProbe) -> list[Any]:
    """Forward pre-hooks on every nn.MultiheadAttention (layer ids = their order in model.modules())."""
    handles = []
    layer = 0
    for m in model.modules():
        if not isinstance(m, nn.MultiheadAttention):
            continue
        if m.bias_k is not None or m.add_zero_attn:
            raise NotImplementedError(
                "probing nn.MultiheadAttention with add_bias_kv/add_zero_attn is not supported"
            )

        def hook(mod: nn.MultiheadAttention, args: tuple, kwargs: dict, _layer: int = layer) -> None:
            if not probe.wants(_layer):
                return
            query = args[0] if args else kwargs["query"]
            key = args[1] if len(args) > 1 else kwargs["key"]
            with own_saved_tensors():
                q, k = _mha_qk(mod, query, key)
                is_causal = kwargs.get("is_causal", False)
                attn_mask = kwargs.get("attn_mask", args[5] if len(args) > 5 else None)
                kpm = kwargs.get("key_padding_mask", args[3] if len(args) > 3 else None)
                mask = _mha_mask(attn_mask, kpm, q.shape[0], q.shape[1])
                if mask is None and is_causal:
                    Tq, Tk = q.shape[2], k.shape[2]
                    mask = torch.ones(Tq, Tk, dtype=torch.bool, device=q.device).tril()
                probe.record(_layer, q, k, mask)

        handles.append(m.register_forward_pre_hook(hook, with_kwargs=True))
        layer += 1
    return handles
