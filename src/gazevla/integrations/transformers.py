"""Gaze regularization for transformers' VLA and VLM classes: PI0, PaliGemma, Idefics3 / SmolVLM, Llava.

    reg = GazeRegularizer(model, {"front": camera_geometry(model, src_hw=(480, 640))}, layers=[1], weight=0.1)
    with reg:                                  # capture differentiable attention during this forward
        out = model(**batch)
    gaze_term, info = reg.loss({"front": gaze})  # gaze: (B, n_patches) on the camera's patch grid
    (out.loss + gaze_term).backward()

How the attention is captured
-----------------------------
transformers' attention modules call `ALL_ATTENTION_FUNCTIONS.get_interface(config._attn_implementation, eager)`
at every forward. Inside `with reg:` the config of the regularized decoder (PI0: the action expert `dit_config`;
the VLMs: the text config) is switched to `gazevla_<base>` (e.g. `gazevla_sdpa`), a function registered with
`transformers.AttentionInterface` (and the base's mask function with `AttentionMaskInterface`, so the masks
are unchanged). It calls the base function with the same arguments (so the model's outputs are bit-identical)
and, on the selected layers only (layer = the module's `layer_idx`), hands the attention's queries and keys to a
`gazevla.attention.AttentionProbe`, which recomputes softmax(q k^T * scale + mask) for the chosen query rows
over all keys (so the probabilities are the model's own) and keeps the columns of the image tokens. On exit the
config is restored.

Which attention
---------------
- PI0 (`PI0ForConditionalGeneration`): the action expert's action tokens (the last `chunk_size` tokens of the
  suffix; `queries="suffix"` adds the state token) attending to the prefix's image tokens, on DiT layers.
- PaliGemma, Idefics3, SmolVLM, Llava: rows of the language model's layers. `queries="last"` (default): the last
  attended token of each sample (the one predicting the first answer/action token); `"labels"`: every position
  that predicts a supervised label (labels[t + 1] != -100, OpenVLA-style action tokens); or explicit positions.
- Keys: the image tokens (`input_ids == config.image_token_id`), several images = several cameras in the order
  the prompt holds them, each block mapped row-major onto its camera's `PatchGeometry` grid (pixel-shuffled
  grids for Idefics3/SmolVLM; Llava's CLS token is skipped under `vision_feature_select_strategy="full"`).
- Heads and queries are averaged per layer, layers averaged, then renormalised over each camera's patch keys.
"""

from __future__ import annotations

import inspect
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn

from gazevla.attention.probe import AttentionProbe, ProbeSpec
from gazevla.losses import Divergence, WeightSchedule, gaze_loss
from gazevla.patches import PatchGeometry

__all__ = [
    "FAMILIES",
    "GazeRegularizer",
    "ModelFamily",
    "camera_geometry",
    "detect_family",
    "gaze_attention_name",
    "register_gaze_attention",
]

_PREFIX = "gazevla_"
_SUPPORTED_BASES = ("sdpa", "eager")


# ----- the registered attention function ----------------------------------------------------------------
@dataclass
class _Capture:
    """What the registered attention function needs while a forward is being captured."""

    probe: AttentionProbe
    layer_of: dict[int, int]  # id(attention module) -> layer index
    queries: Tensor  # (B, n_queries) positions along the attention's query axis
    active: bool = True  # False once the forward is over (gradient-checkpoint recomputation is ignored)


_CAPTURE: ContextVar[_Capture | None] = ContextVar("gazevla_hf_capture", default=None)
_EAGER_CACHE: dict[type, Callable[..., Any]] = {}


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


def _eager_for(module: nn.Module) -> Callable[..., Any]:
    """The eager attention of the module's own modeling file (what `attn_implementation="eager"` runs)."""
    cls = type(module)
    fn = _EAGER_CACHE.get(cls)
    if fn is None:
        fn = getattr(sys.modules.get(cls.__module__), "eager_attention_forward", None) or _generic_eager
        _EAGER_CACHE[cls] = fn
    return fn


def gaze_attention_name(base: str) -> str:
    """Name under which the capturing wrapper of attention implementation `base` is registered."""
    return _PREFIX + base


def _base_of(name: str | None) -> str:
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
    cap = _CAPTURE.get()
    if cap is None or not cap.active:
        return
    layer = cap.layer_of.get(id(module))
    if layer is None or not cap.probe.wants(layer):
        return
    if kwargs.get("softcap") is not None:
        raise NotImplementedError(
            f"gaze capture does not support attention logit soft-capping (layer {layer})"
        )
    scaling = kwargs.get("scaling", args[0] if args else None)
    B, H, Tq, d = query.shape
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

    gaze_attention_forward.__name__ = f"gazevla_{base}_attention_forward"
    return gaze_attention_forward


def register_gaze_attention(base: str = "sdpa") -> str:
    """Register `gazevla_<base>` with transformers' AttentionInterface and AttentionMaskInterface (idempotent).

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


# ----- model families --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ModelFamily:
    """How one family of transformers models lays out image tokens and where its regularized attention lives.

    attention_config(model): the config object read by the regularized attention modules (switched during capture).
    image_token_id(model), tokens_per_image(model): the image placeholder id and how many it repeats per image.
    skip_per_image(model): leading tokens of each image block that are not patches (Llava's CLS under 'full').
    vision(model): (image_size, patch_size, pixel_shuffle) of the vision tower's input.
    default_resize(model), default_pad: the family processor's resize ('stretch'/'fit'/'cover') and padding.
    default_queries: the query selection used when none is given.
    """

    name: str
    class_prefixes: tuple[str, ...]
    attention_config: Callable[[nn.Module], Any]
    image_token_id: Callable[[nn.Module], int]
    vision: Callable[[nn.Module], tuple[int, int, int]]
    default_resize: str
    default_pad: str
    default_queries: str
    skip_per_image: Callable[[nn.Module], int] = lambda model: 0

    def grid_hw(self, model: nn.Module) -> tuple[int, int]:
        size, patch, shuffle = self.vision(model)
        return size // patch // shuffle, size // patch // shuffle

    def tokens_per_image(self, model: nn.Module) -> int:
        h, w = self.grid_hw(model)
        return h * w + self.skip_per_image(model)


def _vision(cfg: Any, shuffle: int = 1) -> tuple[int, int, int]:
    size = cfg.image_size if isinstance(cfg.image_size, int) else cfg.image_size[0]
    patch = cfg.patch_size if isinstance(cfg.patch_size, int) else cfg.patch_size[0]
    return int(size), int(patch), int(shuffle)


def _llava_skip(model: nn.Module) -> int:
    return 1 if getattr(model.config, "vision_feature_select_strategy", "default") == "full" else 0


FAMILIES: dict[str, ModelFamily] = {
    "pi0": ModelFamily(
        name="pi0",
        class_prefixes=("PI0",),
        attention_config=lambda m: m.config.dit_config,
        image_token_id=lambda m: m.config.vlm_config.image_token_id,
        vision=lambda m: _vision(m.config.vlm_config.vision_config),
        default_resize="fit",  # PI0ImageProcessor: fit inside 224x224, pad bottom/right (content at the top-left)
        default_pad="topleft",
        default_queries="actions",
    ),
    "paligemma": ModelFamily(
        name="paligemma",
        class_prefixes=("PaliGemma",),
        attention_config=lambda m: m.config.get_text_config(decoder=True),
        image_token_id=lambda m: m.config.image_token_id,
        vision=lambda m: _vision(m.config.vision_config),
        default_resize="stretch",  # SigLIP processor: resize to (image_size, image_size)
        default_pad="centre",
        default_queries="last",
    ),
    "idefics3": ModelFamily(
        name="idefics3",
        class_prefixes=("Idefics3", "SmolVLM"),
        attention_config=lambda m: m.config.get_text_config(decoder=True),
        image_token_id=lambda m: m.config.image_token_id,
        vision=lambda m: _vision(m.config.vision_config, m.config.scale_factor),
        default_resize="stretch",  # do_image_splitting=False: the image is squared to max_image_size
        default_pad="centre",
        default_queries="last",
    ),
    "llava": ModelFamily(
        name="llava",
        class_prefixes=("Llava",),
        attention_config=lambda m: m.config.get_text_config(decoder=True),
        image_token_id=lambda m: m.config.image_token_id,
        vision=lambda m: _vision(m.config.vision_config),
        default_resize="cover",  # CLIP processor: shortest edge to image_size, centre crop
        default_pad="centre",
        default_queries="last",
        skip_per_image=_llava_skip,
    ),
}


def detect_family(model: nn.Module) -> ModelFamily:
    """The family of a transformers model, from its class name (or its base classes' names)."""
    for cls in type(model).__mro__:
        for fam in FAMILIES.values():
            if cls.__name__.startswith(fam.class_prefixes) and cls.__module__.startswith("transformers."):
                return fam
    known = sorted(p for f in FAMILIES.values() for p in f.class_prefixes)
    raise TypeError(f"no gaze adapter for {type(model).__name__}; supported transformers families: {known}")


def camera_geometry(
    model: nn.Module,
    src_hw: tuple[int, int] | None = None,
    image_processor: Any = None,
    **overrides: Any,
) -> PatchGeometry:
    """The `PatchGeometry` of one camera as `model` sees it, from the model's config and its processor's facts.

    src_hw: the stored frame size (height, width); needed when the processor keeps the aspect ratio (PI0 fits
        and pads, Llava resizes and centre-crops); None assumes frames that are already square.
    image_processor: optional processor (or its image processor) whose resize/pad/crop settings override the
        family's defaults (Llava `do_pad` -> fit centred; Idefics3/SmolVLM `do_image_splitting` is refused).
    overrides: any PatchGeometry field (e.g. orientation, crop_box) set explicitly.
    """
    fam = detect_family(model)
    size, patch, shuffle = fam.vision(model)
    resize, pad = fam.default_resize, fam.default_pad
    proc = getattr(image_processor, "image_processor", image_processor)
    if proc is not None:
        if getattr(proc, "do_image_splitting", False):
            raise ValueError(
                "the image processor splits images into tiles (do_image_splitting=True): each tile is a separate "
                "block of image tokens; use do_image_splitting=False or declare one geometry (crop_box) per tile"
            )
        if fam.name == "llava":
            if getattr(proc, "do_pad", False):
                resize, pad = "fit", "centre"
            elif not getattr(proc, "do_center_crop", True):
                resize = "stretch"
    if src_hw is None and resize != "stretch":
        src_hw = (size, size)
    kwargs: dict[str, Any] = dict(
        input_hw=(size, size), patch_size=patch, src_hw=src_hw, resize=resize, pad=pad, pixel_shuffle=shuffle
    )
    kwargs.update(overrides)
    return PatchGeometry(**kwargs)


# ----- the user-facing regularizer ------------------------------------------------------------------------------
class _Restore:
    def __init__(self, fn: Callable[[], None]):
        self._fn = fn

    def remove(self) -> None:
        fn, self._fn = self._fn, None
        if fn is not None:
            fn()


QuerySpec = str | Sequence[int] | Tensor | Callable[[dict[str, Any]], Tensor]


class GazeRegularizer:
    """Adds the gaze KL to a transformers VLA/VLM's training loss without changing the model.

    Args:
        model: a PI0ForConditionalGeneration, PaliGemma*, Idefics3*/SmolVLM* or Llava* model (sdpa or eager).
        cameras: {camera: PatchGeometry} in the order the prompt holds the images, or a list of camera names
            (each gets `camera_geometry(model)`), or one PatchGeometry / None for a single camera "image".
        layers: indices of the regularized decoder layers (PI0: action-expert layers; VLMs: language-model
            layers); default: the second half (middle-to-late layers).
        weight: the gaze weight, a float or a `WeightSchedule` (evaluated at `loss(..., step=)`).
        queries: which attention rows: PI0 "actions" (default) or "suffix"; VLMs "last" (default) or "labels";
            or explicit positions along the regularized attention's query axis: a (n_queries,) sequence, a
            (B, n_queries) tensor, or a callable(forward_kwargs) -> (B, n_queries).
        divergence: "forward" KL(gaze || attention) (default), "reverse" or "js".

    Usage: `with reg: out = model(**batch)`, then `term, info = reg.loss(gaze, valid)`; `loss = out.loss + term`.
    """

    def __init__(
        self,
        model: nn.Module,
        cameras: Mapping[str, PatchGeometry] | Sequence[str] | PatchGeometry | None = None,
        layers: Iterable[int] | None = None,
        weight: float | WeightSchedule = 0.1,
        queries: QuerySpec | None = None,
        divergence: Divergence = "forward",
        family: ModelFamily | str | None = None,
    ):
        self.model = model
        self.family = FAMILIES[family] if isinstance(family, str) else (family or detect_family(model))
        self.cameras = self._geometries(cameras)
        grid = self.family.grid_hw(model)
        for cam, geom in self.cameras.items():
            try:
                geom.check_grid(grid)
            except ValueError as e:
                raise ValueError(
                    f"camera {cam!r}: {e} ({type(model).__name__} config gives {grid})"
                ) from None
        self.config = self.family.attention_config(model)
        self.modules = self._attention_modules()
        n = len(self.modules)
        self.layers = tuple(range(n // 2, n)) if layers is None else tuple(int(i) for i in layers)
        bad = [i for i in self.layers if not 0 <= i < n]
        if bad or not self.layers:
            raise ValueError(
                f"layers {list(self.layers)} invalid: {type(model).__name__} has {n} regularizable layers (0..{n - 1})"
            )
        self.schedule = weight if isinstance(weight, WeightSchedule) else WeightSchedule(weight=float(weight))
        self.queries = self.family.default_queries if queries is None else queries
        self.divergence = divergence
        self.base = _base_of(self.config._attn_implementation)
        register_gaze_attention(self.base)  # raises for unsupported implementations
        self.probe: AttentionProbe | None = None
        # (B, n_cameras) bool: the camera's image is in the sample (PI0's camera slots), from the last forward
        self.present: Tensor | None = None
        self._hooks: list[Any] = []
        self._signature: inspect.Signature | None = None
        self._cap_token = None
        self._capture: _Capture | None = None

    # ----- setup -----------------------------------------------------------------------------------------------
    def _geometries(self, cameras: Any) -> dict[str, PatchGeometry]:
        if cameras is None:
            return {"image": camera_geometry(self.model)}
        if isinstance(cameras, PatchGeometry):
            return {"image": cameras}
        if isinstance(cameras, Mapping):
            out = dict(cameras)
        else:
            out = {str(c): camera_geometry(self.model) for c in cameras}
        if not out:
            raise ValueError("at least one camera is needed")
        return out

    def _attention_modules(self) -> list[nn.Module]:
        found = {}
        for mod in self.model.modules():
            if (
                getattr(mod, "config", None) is self.config
                and hasattr(mod, "layer_idx")
                and hasattr(mod, "q_proj")
            ):
                found[int(mod.layer_idx)] = mod
        if not found:
            raise RuntimeError(
                f"found no attention modules of {type(self.model).__name__}'s {self.family.name} decoder"
            )
        if sorted(found) != list(range(len(found))):
            raise RuntimeError(f"attention layer_idx values {sorted(found)} are not 0..{len(found) - 1}")
        return [found[i] for i in range(len(found))]

    @property
    def n_layers(self) -> int:
        return len(self.modules)

    # ----- token bookkeeping ---------------------------------------------------------------------------------
    def image_positions(
        self, input_ids: Tensor, pixel_attention_mask: Tensor | None = None
    ) -> tuple[Tensor, Tensor]:
        """Key positions of every camera's patch tokens.

        input_ids: (B, T). pixel_attention_mask: optional (B, n_cameras) bool of present camera slots (PI0).
        Returns keys (B, sum of n_patches over cameras) long, row-major per camera in camera order, and
        present (B, n_cameras) bool (False: that camera's image is absent from the sample; its keys are 0).
        """
        tid = self.family.image_token_id(self.model)
        tpi = self.family.tokens_per_image(self.model)
        skip = self.family.skip_per_image(self.model)
        names = list(self.cameras)
        B = input_ids.shape[0]
        is_img = input_ids == tid
        counts = is_img.sum(-1)
        if pixel_attention_mask is not None:
            pam = pixel_attention_mask.to(torch.bool).cpu()
            if pam.shape != (B, len(names)):
                raise ValueError(
                    f"pixel_attention_mask has shape {tuple(pam.shape)}, but {len(names)} camera(s) {names} are "
                    f"declared for batch {B}: the cameras must match the model's image slots"
                )
        else:
            pam = torch.ones(B, len(names), dtype=torch.bool)
        need = pam.sum(-1) * tpi
        if not torch.equal(counts.cpu(), need):
            b = int((counts.cpu() != need).nonzero()[0, 0])
            cams = " + ".join(
                f"{c} ({self.cameras[c].grid_hw[0]}x{self.cameras[c].grid_hw[1]} grid"
                + (f" + {skip} CLS" if skip else "")
                + f" = {tpi} tokens)"
                for c, on in zip(names, pam[b].tolist())
                if on
            )
            raise ValueError(
                f"sample {b} holds {int(counts[b])} image tokens (image_token_id={tid}) but the declared camera "
                f"geometry needs {int(need[b])}: {cams or 'no camera present'}. The camera/grid mapping does not "
                "match the prompt (wrong number of cameras, image size/patch size/pixel shuffle, or image splitting)"
            )
        pos = torch.arange(input_ids.shape[1], device=input_ids.device)
        keys = torch.zeros(
            B, sum(g.n_patches for g in self.cameras.values()), dtype=torch.long, device=input_ids.device
        )
        for b in range(B):
            p = pos[is_img[b]]
            slot = 0
            offset = 0
            for c, name in enumerate(names):
                n = self.cameras[name].n_patches
                if pam[b, c]:
                    keys[b, offset : offset + n] = p[slot * tpi + skip : (slot + 1) * tpi]
                    slot += 1
                offset += n
        return keys, pam

    def query_positions(self, inputs: dict[str, Any], batch: int, device: torch.device) -> Tensor:
        """(B, n_queries) positions along the regularized attention's query axis for this forward."""
        q = self.queries
        if callable(q):
            q = q(inputs)
        if isinstance(q, str):
            fam = self.family.name
            if fam == "pi0":
                chunk = int(self.model.config.chunk_size)
                if q == "actions":
                    return torch.arange(1, chunk + 1, device=device).expand(batch, -1)
                if q == "suffix":
                    return torch.arange(0, chunk + 1, device=device).expand(batch, -1)
                raise ValueError(f"unknown PI0 queries {q!r}; use 'actions', 'suffix' or explicit positions")
            ids = inputs.get("input_ids")
            T = ids.shape[1]
            if q == "last":
                am = inputs.get("attention_mask")
                if am is None:
                    return torch.full((batch, 1), T - 1, device=device)
                idx = torch.arange(T, device=am.device).expand_as(am)
                return torch.where(am.bool(), idx, -1).amax(-1, keepdim=True).to(device)
            if q == "labels":
                labels = inputs.get("labels")
                if labels is None:
                    raise ValueError("queries='labels' needs `labels` in the forward call")
                sel = labels[:, 1:] != -100  # position t predicts labels[t + 1]
                n = sel.sum(-1)
                if n.min() == 0 or n.min() != n.max():
                    raise ValueError(
                        f"queries='labels' needs the same, non-zero number of supervised tokens per sample, got "
                        f"{n.tolist()}; pass explicit (B, n_queries) positions instead"
                    )
                idx = torch.arange(T - 1, device=labels.device).expand_as(sel)
                return idx[sel].reshape(batch, int(n[0])).to(device)
            raise ValueError(f"unknown queries {q!r}; use 'last', 'labels' or explicit positions")
        t = torch.as_tensor(q, dtype=torch.long, device=device)
        if t.ndim == 1:
            t = t.expand(batch, -1)
        if t.ndim != 2 or t.shape[0] != batch:
            raise ValueError(
                f"query positions must be (n_queries,) or ({batch}, n_queries), got {tuple(t.shape)}"
            )
        return t

    # ----- capture ---------------------------------------------------------------------------------------------
    def _attach(self, model: nn.Module, probe: AttentionProbe) -> list[Any]:
        """Probe adapter: switch the decoder's attention to the capturing function, restore on removal."""
        name = gaze_attention_name(self.base)
        cfg = self.config
        old = cfg._attn_implementation_internal
        cfg._attn_implementation_internal = name

        def restore() -> None:
            cfg._attn_implementation_internal = old

        return [_Restore(restore)]

    def _pre_forward(self, module: nn.Module, args: tuple, kwargs: dict) -> None:
        try:
            if self._signature is None:
                self._signature = inspect.signature(module.forward)
            sig = self._signature
            inputs = dict(sig.bind_partial(*args, **kwargs).arguments)
            for p in sig.parameters.values():
                if p.kind is inspect.Parameter.VAR_KEYWORD:
                    inputs.update(inputs.pop(p.name, {}) or {})
        except TypeError:
            inputs = dict(kwargs)
        ids = inputs.get("input_ids")
        if ids is None:
            raise ValueError(
                "gaze capture needs `input_ids` in the forward call to locate the image tokens "
                f"(config.image_token_id); {type(module).__name__} was called without them"
            )
        pam = inputs.get("pixel_attention_mask") if self.family.name == "pi0" else None
        keys, present = self.image_positions(ids, pam)
        self.present = present.to(ids.device)
        queries = self.query_positions(inputs, ids.shape[0], ids.device)
        spec = ProbeSpec(queries=slice(None), keys=keys, layers=self.layers)
        self._close_probe()
        probe = AttentionProbe(module, spec, adapter=self._attach)
        probe.__enter__()
        self.probe = probe
        self._capture = _Capture(
            probe=probe, layer_of={id(m): i for i, m in enumerate(self.modules)}, queries=queries
        )
        self._cap_token = _CAPTURE.set(self._capture)

    def _post_forward(self, module: nn.Module, args: tuple, kwargs: dict, output: Any) -> None:
        self._close_probe()

    def _close_probe(self) -> None:
        if self._capture is not None:
            self._capture.active = False
        if self._cap_token is not None:
            _CAPTURE.reset(self._cap_token)
            self._cap_token = None
        if self.probe is not None and self.probe._token is not None:
            self.probe.__exit__(None, None, None)

    def __enter__(self) -> GazeRegularizer:
        if self._hooks:
            raise RuntimeError("this GazeRegularizer is already capturing")
        self.probe = None
        self._hooks = [
            self.model.register_forward_pre_hook(self._pre_forward, with_kwargs=True),
            self.model.register_forward_hook(self._post_forward, with_kwargs=True),
        ]
        return self

    def __exit__(self, *exc: object) -> None:
        for h in self._hooks:
            h.remove()
        self._hooks = []
        self._close_probe()

    # ----- results ---------------------------------------------------------------------------------------------
    def _require_probe(self) -> AttentionProbe:
        if self.probe is None:
            raise RuntimeError(
                "no attention captured: run the model's forward inside `with regularizer:` first"
            )
        return self.probe

    def attention(self, eps: float = 1e-12) -> dict[str, Tensor]:
        """{camera: (B, n_patches)} attention of the last captured forward, renormalised per camera."""
        probe = self._require_probe()
        mean = torch.stack([probe.rows(i).mean(dim=(1, 2)) for i in self._checked_layers(probe)]).mean(0)
        out, offset = {}, 0
        for name, geom in self.cameras.items():
            part = mean[:, offset : offset + geom.n_patches]
            out[name] = part / part.sum(-1, keepdim=True).clamp_min(eps)
            offset += geom.n_patches
        return out

    def _checked_layers(self, probe: AttentionProbe) -> list[int]:
        probe._require()
        return probe.layers

    def patch_mass(self) -> Tensor:
        """(B,) mean attention mass the queries put on all cameras' patch tokens (before renormalisation)."""
        return self._require_probe().patch_mass()

    def loss(
        self,
        gaze: Tensor | Mapping[str, Tensor],
        valid: Tensor | Mapping[str, Tensor] | None = None,
        step: int | None = None,
    ) -> tuple[Tensor, dict[str, float]]:
        """weight * mean over cameras of the masked gaze divergence, for the last captured forward.

        gaze: (B, n_patches) for a single camera, or {camera: (B, n_patches)} (cameras missing from the dict are
            not regularized). valid: (B,) bool or {camera: (B,) bool}; absent camera slots are always invalid.
        Returns (weighted loss, info) with info["loss/gaze_kl"] (unweighted), info["gaze/weight"],
        info["gaze/valid_frac"] and info["gaze/patch_mass"].
        """
        att = self.attention()
        if isinstance(gaze, Tensor):
            if len(self.cameras) != 1:
                raise ValueError(
                    f"{len(self.cameras)} cameras {list(self.cameras)}: pass gaze as {{camera: tensor}}"
                )
            gaze = {next(iter(self.cameras)): gaze}
            valid = (
                valid if valid is None or isinstance(valid, Mapping) else {next(iter(self.cameras)): valid}
            )
        unknown = sorted(set(gaze) - set(self.cameras))
        if unknown:
            raise KeyError(
                f"gaze for unknown camera(s) {unknown}; the regularizer's cameras are {list(self.cameras)}"
            )
        names = list(self.cameras)
        terms, fracs = [], []
        for cam, g in gaze.items():
            a = att[cam]
            if g.shape != a.shape:
                raise ValueError(
                    f"gaze for camera {cam!r} has shape {tuple(g.shape)} but the attention over its "
                    f"{self.cameras[cam].grid_hw} patch grid is {tuple(a.shape)}"
                )
            v = torch.ones(a.shape[0], dtype=torch.bool, device=a.device)
            if valid is not None and valid.get(cam) is not None:
                v = valid[cam].to(device=a.device, dtype=torch.bool)
            if self.present is not None:
                v = v & self.present[:, names.index(cam)].to(a.device)
            term, info = gaze_loss(g.to(a.device), a, v, kind=self.divergence)
            terms.append(term)
            fracs.append(info["gaze/valid_frac"])
        kl = torch.stack(terms).mean()
        w = self.schedule(0 if step is None else step)
        info = {
            "loss/gaze_kl": float(kl.detach()),
            "gaze/weight": float(w),
            "gaze/valid_frac": float(sum(fracs) / len(fracs)),
            "gaze/patch_mass": float(self.patch_mass().mean()),
        }
        return w * kl, info
