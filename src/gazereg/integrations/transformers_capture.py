"""The capturing attention function behind `gazereg.integrations.transformers.GazeRegularizer`.

transformers' attention modules call `ALL_ATTENTION_FUNCTIONS.get_interface(config._attn_implementation, eager)`
at every forward. Inside `with reg:` the config of the regularized decoder (PI0: the action expert `dit_config`;
the VLMs: the text config) is switched to `gazereg_<base>` (e.g. `gazereg_sdpa`), a function registered with
`transformers.AttentionInterface` (and the base's mask function with `AttentionMaskInterface`, so the masks
are unchanged). It calls the base function with the same arguments (so the model's outputs are bit-identical)
and, on the selected layers only (layer = the module's `layer_idx`), hands the attention's queries and keys to a
`gazereg.attention.AttentionProbe`, which recomputes softmax(q k^T * scale + mask) for the chosen query rows
over all keys (so the probabilities are the model's own) and keeps the columns of the image tokens. On exit the
config is restored.
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn

from gazereg.attention.probe import AttentionProbe, own_saved_tensors, require_grad_mode
from gazereg.runtime.errors import UsageError

_PREFIX = "gazereg_"
_SUPPORTED_BASES = ("sdpa", "eager")


# ----- the registered attention function ----------------------------------------------------------------
@dataclass
class Capture:
    """What the registered attention function needs while a forward is being captured."""

    probe: AttentionProbe
    layer_of: dict[int, int]  # id(attention module) -> layer index
    queries: Tensor  # (B, n_queries) positions along the attention's query axis
    active: bool = True  # False once the forward is over (gradient-checkpoint recomputation is ignored)
    grad: bool = False  # autograd was on when the forward started (the captured rows must carry a gradient)
    keys: Tensor | None = None  # (B, N) key positions of the patch tokens (range-checked on every layer)
    key_len: int | None = None  # the key axis' length the patch layout implies (inserted patches), or None
    layout: str = ""  # what gave the key positions, for the error messages


CAPTURE: ContextVar[Capture | None] = ContextVar("gazereg_hf_capture", default=None)


def _generic_eager(module, query, key, value, attention_mask, scaling=None, dropout=0.0, **kwargs):
    rep = query.shape[1] // key.shape[1]
    k, v = key.repeat_interleave(rep, 1), value.repeat_interleave(rep, 1)
    scaling = query.shape[-1] ** -0.5 if scaling is None else scaling
    w = torch.matmul(query, k.transpose(2, 3)) * scaling
    if attention_mask is not None:
        w = (
            w.masked_fill(~attention_mask, float("-inf"))
            if attention_mask.dtype == torch.bool
            else w + attention_mask
        )
    w = torch.softmax(w, dim=-1, dtype=torch.float32).to(query.dtype)
    w = nn.functional.dropout(w, p=dropout, training=module.training)
    return torch.matmul(w, v).transpose(1, 2).contiguous(), w


@functools.cache
def _eager_of_class(cls: type) -> Callable[..., Any]:
    return getattr(sys.modules.get(cls.__module__), "eager_attention_forward", None) or _generic_eager


def _eager_for(module: nn.Module) -> Callable[..., Any]:
    """The eager attention of the module's own modeling file (what `attn_implementation="eager"` runs)."""
    return _eager_of_class(type(module))


def gaze_attention_name(base: str) -> str:
    """Name under which the capturing wrapper of attention implementation `base` is registered."""
    return _PREFIX + base


def base_of(name: str | None) -> str:
    """The attention implementation under a (possibly already switched) `gazereg_<base>` name; None -> eager."""
    name = name or "eager"
    while name.startswith(_PREFIX):
        name = name[len(_PREFIX) :]
    return name


def _full_mask(
    mask: Tensor | None, module: nn.Module, base: str, q: Tensor, k: Tensor, kwargs: dict
) -> Tensor | None:
    """The mask the base function applies, in the probe's format (bool True = attend, or additive float)."""
    if mask is not None:
        return mask
    if base != "sdpa":  # eager with no mask attends everywhere
        return None
    # sdpa_attention_forward: no mask + causal module + more than one query -> SDPA's top-left causal mask
    is_causal = kwargs.get("is_causal")
    is_causal = getattr(module, "is_causal", True) if is_causal is None else is_causal
    Tq, Tk = q.shape[2], k.shape[2]
    if not (is_causal and Tq > 1):
        return None
    return torch.ones(Tq, Tk, dtype=torch.bool, device=q.device).tril()[None, None]


def _observe(
    base: str, module: nn.Module, query: Tensor, key: Tensor, mask: Tensor | None, args: tuple, kwargs: dict
):
    cap = CAPTURE.get()
    if cap is None or not cap.active:
        return
    layer = cap.layer_of.get(id(module))
    if layer is None or not cap.probe.wants(layer):
        return
    if module.training:
        require_grad_mode(cap.grad, f"{type(module).__name__} layer {layer}")
    with own_saved_tensors():  # not counted by an enclosing non-reentrant checkpoint
        _record(cap, base, layer, module, query, key, mask, args, kwargs)


def _record(
    cap: Capture,
    base: str,
    layer: int,
    module: nn.Module,
    query: Tensor,
    key: Tensor,
    mask: Tensor | None,
    args: tuple,
    kwargs: dict,
) -> None:
    """Select the capture's query rows (and their mask rows) and hand them to the probe."""
    if kwargs.get("softcap") is not None:
        raise NotImplementedError(
            f"gaze capture does not support attention logit soft-capping (layer {layer})"
        )
    scaling = kwargs.get("scaling", args[0] if args else None)
    B, H, Tq, d = query.shape
    Tk = key.shape[2]
    if cap.key_len is not None and Tk != cap.key_len:
        raise UsageError(
            f"{cap.layout}: layer {layer} attends over {Tk} keys, but input_ids plus the declared patch tokens "
            f"make {cap.key_len}: the patch count or position does not match what the model inserts"
        )
    if cap.keys is not None and cap.keys.numel() and int(cap.keys.max()) >= Tk:
        raise UsageError(
            f"{cap.layout}: image token position {int(cap.keys.max())} is out of range for the {Tk} keys of "
            f"layer {layer}"
        )
    qpos = cap.queries.to(query.device)
    if qpos.shape[0] != B:
        raise ValueError(
            f"query positions are for batch {qpos.shape[0]}, the attention on layer {layer} has batch {B}"
        )
    if qpos.numel() and int(qpos.max()) >= Tq:
        raise ValueError(
            f"query position {int(qpos.max())} is out of range for the {Tq} query tokens of layer {layer}; "
            "check the regularizer's `queries`"
        )
    nq = qpos.shape[1]
    q_sel = query.gather(2, qpos[:, None, :, None].expand(B, H, nq, d))
    m = _full_mask(mask, module, base, query, key, kwargs)
    if m is not None and m.shape[-1] > key.shape[2]:  # masks sized for a longer (static) cache
        m = m[..., : key.shape[2]]
    if m is not None and m.shape[-2] != 1:
        m = m.expand(B, *m.shape[1:]) if m.shape[0] == 1 else m
        m = m.gather(2, qpos[:, None, :, None].expand(B, m.shape[1], nq, m.shape[-1]))
    cap.probe.record(layer, q_sel, key, m, scaling)


def _make_wrapper(base: str) -> Callable[..., Any]:
    if base == "eager":

        def run(module, query, key, value, attention_mask, *args, **kwargs):
            return _eager_for(module)(module, query, key, value, attention_mask, *args, **kwargs)

    else:
        from transformers.modeling_utils import ALL_ATTENTION_FUNCTIONS

        base_fn = ALL_ATTENTION_FUNCTIONS[base]

        def run(module, query, key, value, attention_mask, *args, **kwargs):
            return base_fn(module, query, key, value, attention_mask, *args, **kwargs)

    def gaze_attention_forward(module, query, key, value, attention_mask, *args, **kwargs):
        out = run(module, query, key, value, attention_mask, *args, **kwargs)
        _observe(base, module, query, key, attention_mask, args, kwargs)
        return out

    gaze_attention_forward.__name__ = f"gazereg_{base}_attention_forward"
    return gaze_attention_forward


def register_gaze_attention(base: str = "sdpa") -> str:
    """Register `gazereg_<base>` with transformers' AttentionInterface and AttentionMaskInterface (idempotent).

    The function runs `base` unchanged and feeds the active gaze capture; the mask function is the base's own.
    Returns the registered name."""
    if base not in _SUPPORTED_BASES:
        raise NotImplementedError(
            f"gaze capture supports attn_implementation {list(_SUPPORTED_BASES)}, the model uses {base!r}; "
            "load it with attn_implementation='sdpa' or 'eager'"
        )
    from transformers import AttentionInterface
    from transformers.masking_utils import ALL_MASK_ATTENTION_FUNCTIONS, AttentionMaskInterface

    name = gaze_attention_name(base)
    if name not in AttentionInterface._global_mapping:
        AttentionInterface.register(name, _make_wrapper(base))
    if name not in AttentionMaskInterface._global_mapping:
        AttentionMaskInterface.register(name, ALL_MASK_ATTENTION_FUNCTIONS[base])
    return name


# ----- switching a decoder to the capturing function ----------------------------------------------------------
class _Restore:
    def __init__(self, fn: Callable[[], None]):
        self._fn = fn

    def remove(self) -> None:
        fn, self._fn = self._fn, None
        if fn is not None:
            fn()


def switch_attention(config: Any, base: str) -> list[Any]:
    """Point `config` at the capturing wrapper of `base`; the returned handle's remove() restores it."""
    name = gaze_attention_name(base)
    old = config._attn_implementation_internal
    config._attn_implementation_internal = name

    def restore() -> None:
        config._attn_implementation_internal = old

    return [_Restore(restore)]
