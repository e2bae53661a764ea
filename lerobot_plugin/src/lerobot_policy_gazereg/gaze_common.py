"""What every gaze policy type of this plugin (smolvla_gaze, pi0_gaze, pi05_gaze) shares: the gaze options and
their validation (`GazeOptions`, `validate_gaze_options`), and the gaze term added to the policy's loss
(`add_gaze_term`).

The comment above each `GazeOptions` field is its help text in `lerobot-train --policy.type=<type> --help`
(draccus reads it from this source, looking through a config's base classes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

from torch import Tensor

from gazereg.integrations.gaze_mass import check_target_mass, gaze_mass_kl, gaze_mass_loss
from gazereg.losses import gaze_kl, gaze_loss
from gazereg.patches import PatchGeometry

DIVERGENCES = ("forward", "reverse", "js")


@dataclass
class GazeOptions:
    """The gaze options, mixed in before a LeRobot policy config: `class C(GazeOptions, SmolVLAConfig)` keeps the
    base config's fields first and appends these (config.json gains exactly the `gaze_*` keys)."""

    # Set True where the attention capture needs the eager, uncompiled forward (pi0 / pi05).
    _gaze_eager_only: ClassVar[bool] = False

    # Gaze: weight of KL(gaze || attention) added to the policy's flow-matching loss (0 = the plain policy).
    gaze_weight: float = 0.1
    # Gaze: the data set column holding the gaze, e.g. gaze.point (never under observation.*).
    gaze_key: str = "gaze.point"
    # Gaze: the regularized camera's image feature key (default: the policy's first image feature).
    gaze_camera: str | None = None
    # Gaze: layer indices whose action-token attention is regularized (default: the second half of the layers
    # where the action expert attends).
    gaze_layers: list[int] | None = None
    # Gaze: Gaussian sigma for (u, v) point columns, as a fraction of the frame height.
    gaze_sigma: float = 0.05
    # Gaze: the divergence, forward KL(gaze||attention) | reverse | js.
    gaze_divergence: str = "forward"
    # Gaze: mass variant, pull the attention mass on the camera's image tokens towards m in (0, 1] (default: off).
    gaze_target_mass: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()  # the LeRobot config mixed in after this class
        validate_gaze_options(self)

    def gaze_camera_key(self) -> str:
        """The regularized camera's image feature key."""
        cams = list(self.image_features)
        if not cams:
            raise ValueError("the policy has no image features to regularize")
        cam = self.gaze_camera or cams[0]
        if cam not in cams:
            raise ValueError(f"gaze_camera {cam!r} is not one of the policy's image features {cams}")
        return cam


def validate_gaze_options(cfg: Any) -> None:
    """Raise ValueError naming the first invalid gaze option of a gaze config (a `GazeOptions`)."""
    if not (math.isfinite(cfg.gaze_weight) and cfg.gaze_weight >= 0):
        raise ValueError(f"gaze_weight must be a finite number >= 0, got {cfg.gaze_weight}")
    if cfg.gaze_target_mass is not None and not 0 < cfg.gaze_target_mass <= 1:
        raise ValueError(f"gaze_target_mass must be in (0, 1], got {cfg.gaze_target_mass}")
    if not cfg.gaze_sigma > 0:
        raise ValueError(f"gaze_sigma must be > 0 (fraction of the frame height), got {cfg.gaze_sigma}")
    if cfg.gaze_divergence not in DIVERGENCES:
        raise ValueError(f"gaze_divergence must be forward, reverse or js, got {cfg.gaze_divergence!r}")
    if cfg.gaze_key.startswith("observation."):
        raise ValueError(
            f"gaze_key {cfg.gaze_key!r} is under observation.*, which LeRobot feeds to the policy as an "
            "input; store gaze under another prefix (e.g. gaze.point)"
        )
    if cfg._gaze_eager_only and cfg.gaze_weight > 0 and cfg.compile_model:
        raise ValueError(
            "gaze regularization (gaze_weight > 0) captures attention in the eager forward and cannot run with "
            "compile_model: set it to false or gaze_weight=0"
        )


class Capture(Protocol):
    """What the gaze term reads from a capture (capture.SmolVLACapture, capture_pi0.PiCapture)."""

    def attention(self) -> Tensor: ...
    def raw_attention(self) -> Tensor: ...
    def patch_mass(self) -> Tensor: ...


def gaze_camera_index(cfg: GazeOptions, batch: dict[str, Any]) -> tuple[str, int]:
    """(the regularized camera's key, its position among the batch's images in `cfg.image_features` order)."""
    cam = cfg.gaze_camera_key()
    present = [k for k in cfg.image_features if k in batch]
    if cam not in present:
        raise KeyError(f"gaze camera {cam!r} is missing from the batch (images present: {present})")
    return cam, present.index(cam)


def check_token_count(cam: str, n_tokens: int, geom: PatchGeometry) -> None:
    """Raise ValueError when the camera's image tokens in the forward are not its geometry's patches."""
    if n_tokens != geom.n_patches:
        shuffle = f", pixel shuffle {geom.pixel_shuffle}" if geom.pixel_shuffle != 1 else ""
        raise ValueError(
            f"camera {cam!r} produced {n_tokens} image tokens but its geometry {geom.grid_hw} "
            f"(input {geom.input_hw}, patch {geom.patch_size} px{shuffle}) has {geom.n_patches}: the camera/grid "
            "mapping does not match the model"
        )


def gaze_term(
    capture: Capture, gaze: Tensor, valid: Tensor, kind: str, target_mass: float | None, per_sample: bool
) -> tuple[Tensor, Tensor | None]:
    """(mean divergence () over valid samples, (B,) masked per-sample divergence or None) for gaze (B, N) and
    valid (B,) bool against the captured attention (B, N): renormalised over the camera's tokens, or, with a
    target mass m, raw plus one non-image bin (gazereg.integrations.gaze_mass)."""
    if target_mass is None:
        attention = capture.attention()
        gaze, valid = gaze.to(attention.device), valid.to(attention.device)
        if per_sample:
            rows = gaze_kl(gaze, attention, kind=kind) * valid
            return rows.sum() / valid.sum().clamp_min(1), rows
        return gaze_loss(gaze, attention, valid, kind=kind)[0], None
    mass = check_target_mass(target_mass)
    raw = capture.raw_attention()
    gaze, valid = gaze.to(raw.device), valid.to(raw.device)
    if per_sample:
        rows = gaze_mass_kl(gaze, raw, mass, kind=kind) * valid
        return rows.sum() / valid.sum().clamp_min(1), rows
    return gaze_mass_loss(gaze, raw, mass, valid, kind=kind)[0], None


def add_gaze_term(
    cfg: GazeOptions,
    capture: Capture,
    loss: Tensor,
    loss_dict: dict[str, Any],
    gaze: Tensor,
    valid: Tensor,
    reduction: str,
) -> tuple[Tensor, dict[str, Any]]:
    """loss () or (B,) (reduction "none") + gaze_weight * the gaze term, and the loss dict with `loss/action`,
    `loss/gaze_kl` (unweighted), `gaze/weight`, `gaze/valid_frac` and `gaze/patch_mass` added."""
    kl, per_sample = gaze_term(
        capture, gaze, valid, cfg.gaze_divergence, cfg.gaze_target_mass, reduction == "none"
    )
    w = float(cfg.gaze_weight)
    total = loss + w * (per_sample if reduction == "none" else kl)
    loss_dict.update(
        {
            "loss/action": float(loss.detach().mean()),
            "loss/gaze_kl": float(kl.detach()),
            "gaze/weight": w,
            "gaze/valid_frac": float(valid.float().mean()),
            "gaze/patch_mass": float(capture.patch_mass().mean()),
        }
    )
    return total, loss_dict
