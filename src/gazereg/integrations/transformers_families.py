"""Per-family adapters of the transformers integration: PI0, PaliGemma, Idefics3 / SmolVLM, Llava.

A `ModelFamily` says where a family's regularized attention lives and how it lays out image tokens;
`camera_geometry` turns that into a camera's `PatchGeometry`, and `image_positions` / `query_positions` locate
the attention's keys (every camera's patch tokens) and query rows in one forward (see
gazereg.integrations.transformers, "Which attention").
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn

from gazereg.patches import PatchGeometry

QuerySpec = str | Sequence[int] | Tensor | Callable[[dict[str, Any]], Tensor]


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


# ----- token location ----------------------------------------------------------------------------------
def image_positions(
    family: ModelFamily,
    model: nn.Module,
    cameras: Mapping[str, PatchGeometry],
    input_ids: Tensor,
    pixel_attention_mask: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """Key positions of every camera's patch tokens in `model`'s prompt (cameras in the prompt's image order).

    input_ids: (B, T). pixel_attention_mask: optional (B, n_cameras) bool of present camera slots (PI0).
    Returns keys (B, sum of n_patches over cameras) long, row-major per camera in camera order, and
    present (B, n_cameras) bool (False: that camera's image is absent from the sample; its keys are 0).
    """
    tid = family.image_token_id(model)
    tpi = family.tokens_per_image(model)
    skip = family.skip_per_image(model)
    names = list(cameras)
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
            f"{c} ({cameras[c].grid_hw[0]}x{cameras[c].grid_hw[1]} grid"
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
        B, sum(g.n_patches for g in cameras.values()), dtype=torch.long, device=input_ids.device
    )
    for b in range(B):
        p = pos[is_img[b]]
        slot = 0
        offset = 0
        for c, name in enumerate(names):
            n = cameras[name].n_patches
            if pam[b, c]:
                keys[b, offset : offset + n] = p[slot * tpi + skip : (slot + 1) * tpi]
                slot += 1
            offset += n
    return keys, pam


def query_positions(
    family: ModelFamily,
    model: nn.Module,
    queries: QuerySpec,
    inputs: dict[str, Any],
    batch: int,
    device: torch.device,
) -> Tensor:
    """(B, n_queries) positions along the regularized attention's query axis for this forward."""
    q = queries
    if callable(q):
        q = q(inputs)
    if isinstance(q, str):
        fam = family.name
        if fam == "pi0":
            chunk = int(model.config.chunk_size)
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
