"""Where the gaze term's keys (every camera's patch tokens) and query rows are in one forward of a transformers
model, for the families of gazereg.integrations.transformers_families: placeholder image tokens found by
`image_token_id`, patches inserted at the family's `inserted_at` (OpenVLA: after BOS), or positions the caller
gives (`GazeRegularizer(..., patch_positions=)`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import torch
from torch import Tensor, nn

from gazereg.integrations.transformers_families import ModelFamily
from gazereg.patches import PatchGeometry
from gazereg.runtime.errors import UsageError

QuerySpec = str | Sequence[int] | Tensor | Callable[[dict[str, Any]], Tensor]
# Key positions given by the caller: (N,) for every sample, (B, N), or a callable(forward_kwargs) -> (B, N)
PositionSpec = Sequence[int] | Tensor | Callable[[dict[str, Any]], Tensor]


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
    A family with `inserted_at` gives [inserted_at, inserted_at + N) for every sample (N = the cameras' patches).
    """
    if family.inserted_at is not None:
        return _inserted_positions(family.inserted_at, cameras, input_ids)
    assert family.image_token_id is not None
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
        _count_mismatch(cameras, pam, counts.cpu(), need, tid, tpi, skip)
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


def _inserted_positions(
    start: int, cameras: Mapping[str, PatchGeometry], input_ids: Tensor
) -> tuple[Tensor, Tensor]:
    """[start, start + N) for every sample (N = the cameras' patches), every camera present."""
    n = sum(g.n_patches for g in cameras.values())
    keys = torch.arange(start, start + n, device=input_ids.device).expand(input_ids.shape[0], -1)
    return keys, torch.ones(input_ids.shape[0], len(cameras), dtype=torch.bool)


def _count_mismatch(
    cameras: Mapping[str, PatchGeometry],
    pam: Tensor,
    counts: Tensor,
    need: Tensor,
    tid: int,
    tpi: int,
    skip: int,
) -> None:
    """Raise the error naming the first sample whose image token count is not the cameras' need."""
    b = int((counts != need).nonzero()[0, 0])
    cams = " + ".join(
        f"{c} ({cameras[c].grid_hw[0]}x{cameras[c].grid_hw[1]} grid"
        + (f" + {skip} CLS" if skip else "")
        + f" = {tpi} tokens)"
        for c, on in zip(cameras, pam[b].tolist())
        if on
    )
    raise ValueError(
        f"sample {b} holds {int(counts[b])} image tokens (image_token_id={tid}) but the declared camera "
        f"geometry needs {int(need[b])}: {cams or 'no camera present'}. The camera/grid mapping does not "
        "match the prompt (wrong number of cameras, image size/patch size/pixel shuffle, or image splitting)"
    )


def check_position_count(n: int, cameras: Mapping[str, PatchGeometry], what: str) -> None:
    """Refuse (one line) `n` key positions that are not the declared cameras' patch count."""
    need = sum(g.n_patches for g in cameras.values())
    if n != need:
        grids = " + ".join(f"{c} {g.grid_hw[0]}x{g.grid_hw[1]}" for c, g in cameras.items())
        raise UsageError(
            f"{what}: {n} image token positions given, but the cameras' patch grids ({grids}) need {need}"
        )


def given_positions(
    spec: PositionSpec, cameras: Mapping[str, PatchGeometry], inputs: dict[str, Any], batch: int, device: Any
) -> Tensor:
    """(B, N) key positions from the caller's `patch_positions` (see `PositionSpec`), N checked against the
    cameras' patch count (row-major per camera, in camera order)."""
    t = spec(inputs) if callable(spec) else spec
    t = torch.as_tensor(t, dtype=torch.long, device=device)
    if t.ndim == 1:
        t = t.expand(batch, -1)
    if t.ndim != 2 or t.shape[0] != batch:
        raise UsageError(f"patch_positions must be (N,) or ({batch}, N), got shape {tuple(t.shape)}")
    check_position_count(int(t.shape[1]), cameras, "patch_positions")
    if t.numel() and int(t.min()) < 0:
        raise UsageError(f"patch_positions: position {int(t.min())} is negative")
    return t


def shift_inserted(family: ModelFamily, positions: Tensor, n_inserted: int) -> Tensor:
    """Input positions -> the language model's sequence for an `inserted_at` family (p >= inserted_at moves by
    the N inserted patch tokens); unchanged for placeholder families."""
    if family.inserted_at is None:
        return positions
    return torch.where(positions >= family.inserted_at, positions + n_inserted, positions)


def query_positions(
    family: ModelFamily,
    model: nn.Module,
    queries: QuerySpec,
    inputs: dict[str, Any],
    batch: int,
    device: torch.device,
    n_inserted: int = 0,
) -> Tensor:
    """(B, n_queries) positions along the regularized attention's query axis for this forward.

    "last" / "labels" are found on input_ids / labels and, for an `inserted_at` family, moved past the
    `n_inserted` patch tokens; explicit positions are already on the attention's query axis."""
    q = queries
    if callable(q):
        q = q(inputs)
    if isinstance(q, str) and family.name == "pi0":
        chunk = int(model.config.chunk_size)
        if q == "actions":
            return torch.arange(1, chunk + 1, device=device).expand(batch, -1)
        if q == "suffix":
            return torch.arange(0, chunk + 1, device=device).expand(batch, -1)
        raise ValueError(f"unknown PI0 queries {q!r}; use 'actions', 'suffix' or explicit positions")
    if isinstance(q, str):
        return shift_inserted(family, _text_queries(q, inputs, batch, device), n_inserted)
    t = torch.as_tensor(q, dtype=torch.long, device=device)
    if t.ndim == 1:
        t = t.expand(batch, -1)
    if t.ndim != 2 or t.shape[0] != batch:
        raise ValueError(
            f"query positions must be (n_queries,) or ({batch}, n_queries), got {tuple(t.shape)}"
        )
    return t


def _text_queries(q: str, inputs: dict[str, Any], batch: int, device: torch.device) -> Tensor:
    """A VLM's "last" / "labels" query rows on the input_ids axis."""
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


def has_gaze_target(family: ModelFamily, model: nn.Module, given: bool, inputs: dict[str, Any]) -> bool:
    """False for a forward with nothing to regularize: no image tokens in input_ids (or no input_ids) and either
    autograd off (inference, generate) or a non-empty cache (a decoding / denoising step). Without an image token
    id (inserted patches, or `given` positions from the caller) a forward has images when it gets
    `pixel_values` and does not continue a non-empty cache."""
    ids = inputs.get("input_ids")
    past = inputs.get("past_key_values")
    cached = past is not None and (not hasattr(past, "get_seq_length") or int(past.get_seq_length()) > 0)
    if family.image_token_id is None or given:
        if ids is not None and inputs.get("pixel_values") is not None and not cached:
            return True
    elif ids is not None and bool((ids == family.image_token_id(model)).any()):
        return True
    return not (cached or not torch.is_grad_enabled())
