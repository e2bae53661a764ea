"""Per-family adapters of the transformers integration: PI0, PaliGemma, Idefics3 / SmolVLM, Llava, and models
without an image token id (OpenVLA / Prismatic: patch embeddings inserted after BOS).

A `ModelFamily` says where a family's regularized attention lives and how it lays out image tokens;
`camera_geometry` turns that into a camera's `PatchGeometry`; gazereg.integrations.transformers_positions locates
the attention's keys (every camera's patch tokens) and query rows in one forward (see
gazereg.integrations.transformers, "Which attention").

Two layouts of the image tokens:
- placeholders: input_ids hold `image_token_id` once per patch token (the built-in families); the language
  model's sequence is input_ids, and the keys are where the placeholders are.
- inserted (`inserted_at` set, `image_token_id` None): input_ids hold no image tokens; the model inserts every
  camera's patch embeddings, one block per camera in camera order, into the language model's sequence before
  input position `inserted_at` (OpenVLA: 1, right after BOS). The keys are [inserted_at, inserted_at + N) (N =
  the cameras' patch count), and an input position p >= inserted_at is p + N in the language model's sequence.
  `inserted_patch_family` builds such a family and `register_family` makes `detect_family` find it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from torch import nn

from gazereg.patches import PatchGeometry


# ----- model families --------------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class ModelFamily:
    """How one family of transformers models lays out image tokens and where its regularized attention lives.

    attention_config(model): the config object read by the regularized attention modules (switched during capture).
    image_token_id(model), tokens_per_image(model): the image placeholder id and how many it repeats per image;
        None for a model without one (then `inserted_at` says where the patches are).
    inserted_at: None for placeholder image tokens; an int: the model inserts the patch embeddings into the
        language model's sequence before this input_ids position (OpenVLA: 1, after BOS), see the module docstring.
    skip_per_image(model): leading tokens of each image block that are not patches (Llava's CLS under 'full').
    vision(model): (image_size, patch_size, pixel_shuffle) of the vision tower's input.
    default_resize(model), default_pad: the family processor's resize ('stretch'/'fit'/'cover') and padding.
    default_queries: the query selection used when none is given.
    builtin: a transformers class (matched only in `transformers.*` modules); registered families match any module.
    """

    name: str
    class_prefixes: tuple[str, ...]
    attention_config: Callable[[nn.Module], Any]
    vision: Callable[[nn.Module], tuple[int, int, int]]
    default_resize: str
    default_pad: str
    default_queries: str
    image_token_id: Callable[[nn.Module], int] | None = None
    inserted_at: int | None = None
    skip_per_image: Callable[[nn.Module], int] = lambda model: 0
    builtin: bool = False

    def __post_init__(self) -> None:
        if (self.image_token_id is None) == (self.inserted_at is None):
            raise ValueError(
                f"model family {self.name!r}: give exactly one of image_token_id (placeholder image tokens) "
                "and inserted_at (patch embeddings inserted at a fixed position)"
            )
        if self.inserted_at is not None and (isinstance(self.inserted_at, bool) or self.inserted_at < 0):
            raise ValueError(
                f"model family {self.name!r}: inserted_at must be an int >= 0, got {self.inserted_at!r}"
            )

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
        builtin=True,
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
        builtin=True,
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
        builtin=True,
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
        builtin=True,
    ),
}


def inserted_patch_family(
    name: str,
    attention_config: Callable[[nn.Module], Any],
    image_size: int,
    patch_size: int,
    inserted_at: int = 1,
    class_prefixes: Sequence[str] = (),
    default_resize: str = "stretch",
    default_queries: str = "labels",
) -> ModelFamily:
    """A family whose model has no image token id and inserts every camera's patch embeddings (one block of
    (image_size // patch_size)^2 tokens per camera, in camera order) into the language model's sequence before
    input_ids position `inserted_at` (OpenVLA / Prismatic: 1, after BOS).

    attention_config(model): the language model's config (OpenVLA: `model.language_model.config`).
    image_size, patch_size: pixels (OpenVLA: 224 and 14, 16x16 = 256 patches, SigLIP and DINOv2 features fused
    per patch). class_prefixes: class names that `detect_family` maps to it once registered (`register_family`).
    """
    if not (isinstance(image_size, int) and isinstance(patch_size, int) and 0 < patch_size <= image_size):
        raise ValueError(
            f"image_size {image_size!r} and patch_size {patch_size!r} must be ints, 0 < patch <= image"
        )
    size, patch = int(image_size), int(patch_size)
    return ModelFamily(
        name=name,
        class_prefixes=tuple(class_prefixes),
        attention_config=attention_config,
        vision=lambda m: (size, patch, 1),
        default_resize=default_resize,
        default_pad="centre",
        default_queries=default_queries,
        inserted_at=inserted_at,
    )


def register_family(family: ModelFamily) -> ModelFamily:
    """Add a family to FAMILIES (by name), so `detect_family` and `GazeRegularizer(family=name)` find it.
    A registered family matches its class prefixes in any module (e.g. trust_remote_code classes)."""
    if family.name in FAMILIES and FAMILIES[family.name].builtin:
        raise ValueError(
            f"{family.name!r} is a built-in gaze model family; register yours under another name"
        )
    FAMILIES[family.name] = family
    return family


def detect_family(model: nn.Module) -> ModelFamily:
    """The family of a model, from its class name (or its base classes' names): the built-in families match
    transformers' own classes, registered ones (`register_family`) their class prefixes in any module."""
    for cls in type(model).__mro__:
        for fam in FAMILIES.values():
            named = bool(fam.class_prefixes) and cls.__name__.startswith(fam.class_prefixes)
            if named and (not fam.builtin or cls.__module__.startswith("transformers.")):
                return fam
    known = sorted(p for f in FAMILIES.values() for p in f.class_prefixes)
    raise TypeError(
        f"no gaze adapter for {type(model).__name__}; supported families: {known} (a model without an image "
        "token id: register one with inserted_patch_family + register_family, or pass family=)"
    )


def camera_geometry(
    model: nn.Module,
    src_hw: tuple[int, int] | None = None,
    image_processor: Any = None,
    family: ModelFamily | None = None,
    **overrides: Any,
) -> PatchGeometry:
    """The `PatchGeometry` of one camera as `model` sees it, from the model's config and its processor's facts.

    src_hw: the stored frame size (height, width); needed when the processor keeps the aspect ratio (PI0 fits
        and pads, Llava resizes and centre-crops); None assumes frames that are already square.
    image_processor: optional processor (or its image processor) whose resize/pad/crop settings override the
        family's defaults (Llava `do_pad` -> fit centred; Idefics3/SmolVLM `do_image_splitting` is refused).
    family: the model's family when it is not detected from its class (default: `detect_family(model)`).
    overrides: any PatchGeometry field (e.g. orientation, crop_box) set explicitly.
    """
    fam = family or detect_family(model)
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


def camera_geometries(model: nn.Module, family: ModelFamily, cameras: Any) -> dict[str, PatchGeometry]:
    """{camera: PatchGeometry} from a GazeRegularizer's `cameras` argument (see there)."""
    if cameras is None:
        return {"image": camera_geometry(model, family=family)}
    if isinstance(cameras, PatchGeometry):
        return {"image": cameras}
    if isinstance(cameras, Mapping):
        out = dict(cameras)
    else:
        out = {str(c): camera_geometry(model, family=family) for c in cameras}
    if not out:
        raise ValueError("at least one camera is needed")
    return out


def attention_modules(model: nn.Module, config: Any, family_name: str) -> list[nn.Module]:
    """The attention modules that read `config` (the regularized decoder's), in layer_idx order 0..n-1."""
    found = {}
    for mod in model.modules():
        if getattr(mod, "config", None) is config and hasattr(mod, "layer_idx") and hasattr(mod, "q_proj"):
            found[int(mod.layer_idx)] = mod
    if not found:
        raise RuntimeError(f"found no attention modules of {type(model).__name__}'s {family_name} decoder")
    if sorted(found) != list(range(len(found))):
        raise RuntimeError(f"attention layer_idx values {sorted(found)} are not 0..{len(found) - 1}")
    return [found[i] for i in range(len(found))]
