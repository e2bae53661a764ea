"""Gaze regularization for transformers' VLA and VLM classes: PI0, PaliGemma, Idefics3 / SmolVLM, Llava, and
models without an image token id whose patch embeddings sit at known positions (OpenVLA / Prismatic).

    reg = GazeRegularizer(model, {"front": camera_geometry(model, src_hw=(480, 640))}, layers=[1], weight=0.1)
    with reg:                                  # capture differentiable attention during this forward
        out = model(**batch)
    gaze_term, info = reg.loss({"front": gaze})  # gaze: (B, n_patches) on the camera's patch grid
    (out.loss + gaze_term).backward()

How the attention is captured: inside `with reg:` the regularized decoder's attention implementation is
switched to a registered wrapper (`gazereg_sdpa` / `gazereg_eager`) that runs the original unchanged and
hands the selected layers' queries and keys to a `gazereg.attention.AttentionProbe`
(gazereg.integrations.transformers_capture). The per-family adapters (image tokens, patch grids) are in
gazereg.integrations.transformers_families, the key and query positions in ...transformers_positions.

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
- Models without an image token id (OpenVLA: a Llama-2 decoder, the image's patch embeddings inserted after BOS):
  the keys come from the family's `inserted_at` layout (`inserted_patch_family` + `register_family`, or
  `family=`), or from the caller (`patch_positions=`: (N,), (B, N) or a callable(forward_kwargs) -> (B, N)
  positions in the language model's sequence, N = the cameras' patch count, checked). With an inserted layout
  "last" / "labels" are found on input_ids / labels and moved past the inserted patches, and every captured
  layer's key axis must be input_ids' length + N (a wrong patch count is refused in one line).
- Heads and queries are averaged per layer, layers averaged, then renormalised over each camera's patch keys.

Gradient checkpointing: non-reentrant (`gradient_checkpointing_enable()`, transformers' default) works, the
term's gradient is the one without checkpointing; reentrant (`use_reentrant=True`) runs the layers without
autograd, so the capture raises a UsageError at the first training forward instead of logging a term that is
never optimised.

Forwards without a gaze target are skipped: a forward whose input_ids hold no image tokens (or that has no
input_ids) and that runs under no_grad or continues a non-empty cache (`generate()`'s decoding steps, PI0
`sample_actions()`'s denoising steps) captures nothing; the last captured forward stays readable.

Image mass: `info["gaze/patch_mass"]` is the attention mass on the present cameras' patch tokens (in [0, 1]).
`target_mass=m` switches the term to the mass variant (gazereg.integrations.gaze_mass), which also pulls that
mass towards m, so the KL cannot be met by looking away from the image.
"""

from __future__ import annotations

import inspect
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import torch
from torch import Tensor, nn

from gazereg.attention.probe import AttentionProbe, ProbeSpec
from gazereg.integrations.gaze_mass import check_target_mass, gaze_mass_loss
from gazereg.integrations.transformers_capture import (
    CAPTURE,
    Capture,
    base_of,
    gaze_attention_name,
    register_gaze_attention,
    switch_attention,
)
from gazereg.integrations.transformers_families import (
    FAMILIES,
    ModelFamily,
    attention_modules,
    camera_geometries,
    camera_geometry,
    detect_family,
    inserted_patch_family,
    register_family,
)
from gazereg.integrations.transformers_positions import (
    PositionSpec,
    QuerySpec,
    check_position_count,
    given_positions,
    has_gaze_target,
    image_positions,
    query_positions,
)
from gazereg.losses import Divergence, WeightSchedule, gaze_loss
from gazereg.patches import PatchGeometry

__all__ = [
    "FAMILIES",
    "GazeRegularizer",
    "ModelFamily",
    "camera_geometry",
    "detect_family",
    "gaze_attention_name",
    "inserted_patch_family",
    "register_family",
    "register_gaze_attention",
]


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
        target_mass: None (default): the divergence over each camera's renormalised patch attention; a number m
            in (0, 1]: the mass variant over patches + one non-image bin with target mass m on the image.
        family: the model's `ModelFamily` (or a registered name) when it is not detected from the class.
        patch_positions: the patch tokens' key positions in the regularized attention's sequence, given by the
            caller instead of the family's layout: (N,) for every sample, (B, N), or a callable(forward_kwargs)
            -> (B, N); N = the cameras' patch count (row-major per camera, in camera order), else a UsageError.

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
        target_mass: float | None = None,
        patch_positions: PositionSpec | None = None,
    ):
        self.model = model
        self.family = FAMILIES[family] if isinstance(family, str) else (family or detect_family(model))
        self.patch_positions = patch_positions
        self.cameras = camera_geometries(model, self.family, cameras)
        grid = self.family.grid_hw(model)
        for cam, geom in self.cameras.items():
            try:
                geom.check_grid(grid)
            except ValueError as e:
                raise ValueError(
                    f"camera {cam!r}: {e} ({type(model).__name__} config gives {grid})"
                ) from None
        self.config = self.family.attention_config(model)
        self.modules = attention_modules(model, self.config, self.family.name)
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
        self.target_mass = None if target_mass is None else check_target_mass(target_mass)
        if patch_positions is not None and not callable(patch_positions):
            shape = torch.as_tensor(patch_positions).shape
            check_position_count(int(shape[-1]) if len(shape) else 0, self.cameras, "patch_positions")
        self.skipped = 0  # forwards skipped since __enter__ (no image tokens: decoding / denoising steps)
        self.base = base_of(self.config._attn_implementation)
        register_gaze_attention(self.base)  # raises for unsupported implementations
        self.probe: AttentionProbe | None = None
        # (B, n_cameras) bool: the camera's image is in the sample (PI0's camera slots), from the last forward
        self.present: Tensor | None = None
        self._hooks: list[Any] = []
        self._signature: inspect.Signature | None = None
        self._cap_token = None
        self._capture: Capture | None = None

    @property
    def n_layers(self) -> int:
        return len(self.modules)

    # ----- token bookkeeping ---------------------------------------------------------------------------------
    def image_positions(
        self,
        input_ids: Tensor,
        pixel_attention_mask: Tensor | None = None,
        inputs: dict[str, Any] | None = None,
    ) -> tuple[Tensor, Tensor]:
        """Key positions of every camera's patch tokens.

        input_ids: (B, T). pixel_attention_mask: optional (B, n_cameras) bool of present camera slots (PI0).
        inputs: the forward's keyword arguments (for a callable `patch_positions`).
        Returns keys (B, sum of n_patches over cameras) long, row-major per camera in camera order, and
        present (B, n_cameras) bool (False: that camera's image is absent from the sample; its keys are 0).
        """
        if self.patch_positions is not None:
            B = input_ids.shape[0]
            keys = given_positions(
                self.patch_positions, self.cameras, inputs or {"input_ids": input_ids}, B, input_ids.device
            )
            return keys, torch.ones(B, len(self.cameras), dtype=torch.bool)
        return image_positions(self.family, self.model, self.cameras, input_ids, pixel_attention_mask)

    @property
    def n_patches(self) -> int:
        """N: the patch tokens of all cameras (the keys of the regularized attention)."""
        return sum(g.n_patches for g in self.cameras.values())

    def query_positions(self, inputs: dict[str, Any], batch: int, device: torch.device) -> Tensor:
        """(B, n_queries) positions along the regularized attention's query axis for this forward."""
        return query_positions(
            self.family, self.model, self.queries, inputs, batch, device, n_inserted=self.n_patches
        )

    # ----- capture ---------------------------------------------------------------------------------------------
    def _attach(self, model: nn.Module, probe: AttentionProbe) -> list[Any]:
        """Probe adapter: switch the decoder's attention to the capturing function, restore on removal."""
        return switch_attention(self.config, self.base)

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
        if not has_gaze_target(self.family, self.model, self.patch_positions is not None, inputs):
            self.skipped += 1
            return
        if ids is None:
            raise ValueError(
                "gaze capture needs `input_ids` in the forward call to locate the image tokens "
                f"(config.image_token_id); {type(module).__name__} was called without them"
            )
        pam = inputs.get("pixel_attention_mask") if self.family.name == "pi0" else None
        keys, present = self.image_positions(ids, pam, inputs)
        self.present = present.to(ids.device)
        queries = self.query_positions(inputs, ids.shape[0], ids.device)
        inserted = self.family.inserted_at is not None and self.patch_positions is None
        spec = ProbeSpec(queries=slice(None), keys=keys, layers=self.layers)
        self._close_probe()
        probe = AttentionProbe(module, spec, adapter=self._attach)
        probe.__enter__()
        self.probe = probe
        self._capture = Capture(
            probe=probe,
            layer_of={id(m): i for i, m in enumerate(self.modules)},
            queries=queries,
            grad=torch.is_grad_enabled(),
            keys=keys,
            key_len=ids.shape[1] + self.n_patches if inserted else None,
            layout=(
                "patch_positions"
                if self.patch_positions is not None
                else f"the {self.family.name} family's patches at {self.family.inserted_at}.."
                f"{self.family.inserted_at + self.n_patches - 1}"
                if inserted
                else f"the {self.family.name} family's image tokens"
            ),
        )
        self._cap_token = CAPTURE.set(self._capture)

    def _post_forward(self, module: nn.Module, args: tuple, kwargs: dict, output: Any) -> None:
        self._close_probe()

    def _close_probe(self) -> None:
        if self._capture is not None:
            self._capture.active = False
        if self._cap_token is not None:
            CAPTURE.reset(self._cap_token)
            self._cap_token = None
        if self.probe is not None and self.probe._token is not None:
            self.probe.__exit__(None, None, None)

    def __enter__(self) -> GazeRegularizer:
        if self._hooks:
            raise RuntimeError("this GazeRegularizer is already capturing")
        self.probe = None
        self.skipped = 0
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
            why = (
                f": the {self.skipped} forward(s) inside held no image tokens (generate()'s decoding steps and "
                "PI0 sample_actions() are skipped); run a training forward with input_ids holding the images"
                if self.skipped
                else ""
            )
            raise RuntimeError(
                f"no attention captured: run the model's forward inside `with regularizer:` first{why}"
            )
        return self.probe

    def raw_attention(self) -> dict[str, Tensor]:
        """{camera: (B, n_patches)} attention of the last captured forward, averaged over heads, queries and
        layers but NOT renormalised (row sum = the camera's image mass); an absent camera's rows are 0."""
        mean = self._require_probe().mean_rows()
        out, offset = {}, 0
        for c, (name, geom) in enumerate(self.cameras.items()):
            part = mean[:, offset : offset + geom.n_patches]
            if self.present is not None:  # absent slots point at key 0: not the camera's mass
                part = part * self.present[:, c].to(device=part.device, dtype=part.dtype)[:, None]
            out[name] = part
            offset += geom.n_patches
        return out

    def attention(self, eps: float = 1e-12) -> dict[str, Tensor]:
        """{camera: (B, n_patches)} attention of the last captured forward, renormalised per camera."""
        return {
            name: part / part.sum(-1, keepdim=True).clamp_min(eps)
            for name, part in self.raw_attention().items()
        }

    def patch_mass(self) -> Tensor:
        """(B,) attention mass the queries put on the present cameras' patch tokens (before renormalisation),
        in [0, 1]; detached."""
        return torch.stack([a.sum(-1) for a in self.raw_attention().values()]).sum(0).detach()

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
        info["gaze/valid_frac"] and info["gaze/patch_mass"] (attention mass on the present cameras' patches).
        """
        raw = self.raw_attention()
        att = {c: a / a.sum(-1, keepdim=True).clamp_min(1e-12) for c, a in raw.items()}
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
            if self.target_mass is None:
                term, info = gaze_loss(g.to(a.device), a, v, kind=self.divergence)
            else:
                term, info = gaze_mass_loss(g, raw[cam], self.target_mass, v, kind=self.divergence)
            terms.append(term)
            fracs.append(info["gaze/valid_frac"])
        kl = torch.stack(terms).mean()
        w = self.schedule(0 if step is None else step)
        info = {
            "loss/gaze_kl": float(kl.detach()),
            "gaze/weight": float(w),
            "gaze/valid_frac": float(sum(fracs) / len(fracs)),
            "gaze/patch_mass": float(torch.stack([a.detach().sum(-1) for a in raw.values()]).sum(0).mean()),
        }
        return w * kl, info
