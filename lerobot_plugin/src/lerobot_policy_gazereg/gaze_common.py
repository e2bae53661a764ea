"""What every gaze policy type of this plugin (smolvla_gaze, pi0_gaze, pi05_gaze) shares: the gaze options and
their validation (`GazeOptions`, `validate_gaze_options`), the checks of the data set's gaze column when the policy
is built (`check_gaze_features`, `check_gaze_layers`, build_checks.check_before_build) and while it trains
(`GazeActivity`), and the gaze term added to the policy's loss (`add_gaze_term`, at the end of each training
forward: `finish_gaze_forward`).

Several processes (`accelerate launch --multi_gpu --num_processes N lerobot-train ...`, DDP): the gaze term is a
mean over the valid frames of the GLOBAL batch, as in one process on the same batch. Each process's term is its
sum over its own valid frames times N / (valid frames over all processes) (`gazereg.losses.across_processes`: one all-reduce of
the count per training forward, so every process must run the training forward at every step), so DDP's average of
the processes' gradients and lerobot-train's average of the logged `loss/gaze_kl` are that global mean; a plain
per-process mean would weight a frame by 1 / (its process's valid count) and differ whenever the processes hold
different numbers of frames with gaze.

Every check raises errors.GazeUsageError naming the option or column; inside lerobot-train it is printed as one
line with exit status 2 (errors.refusing). When each check runs:
- the options (`validate_gaze_options`): when the config is built, i.e. while lerobot-train parses its command line;
- the gaze column's presence and shape per frame, the flag column and `gaze_camera` (`check_gaze_features`): in
  the config's `set_dataset_feature_metadata`, which lerobot's make_policy calls with the data set's features
  before it builds the policy (before any weights load);
- `gaze_layers` against the model's layers, the column's content (gaze_data.check_gaze_data: a data set whose
  whole gaze column has no usable frame is refused) and a token-distribution column's length against the camera's
  token grid (build_checks.check_before_build): at the start of the policy's __init__, before the model is built
  and weights load;
- while training (`GazeActivity`): when the first INACTIVE_FRAMES_LIMIT training frames (counted over batches)
  all lack usable gaze, e.g. because the episodes trained on (--dataset.episodes) have none.

The comment above each `GazeOptions` field is its help text in `lerobot-train --policy.type=<type> --help`
(draccus reads it from this source, looking through a config's base classes).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

from torch import Tensor

from gazereg.integrations.gaze_mass import check_target_mass, gaze_mass_kl, gaze_mass_loss
from gazereg.losses import across_processes, gaze_kl, gaze_loss
from gazereg.patches import PatchGeometry

from .errors import GazeUsageError, refusing
from .gaze_targets import gaze_distribution, gaze_kind, gaze_valid_key

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
        with refusing():
            validate_gaze_options(self)

    def set_dataset_feature_metadata(self, features: Mapping[str, Mapping[str, Any]]) -> None:
        """lerobot's make_policy hook, called with the data set's features before the policy is built: checks the
        gaze column, its shape per frame and the regularized camera (check_gaze_features)."""
        base = getattr(super(), "set_dataset_feature_metadata", None)
        if callable(base):
            base(features)
        with refusing():
            check_gaze_features(self, features)

    def gaze_camera_key(self) -> str:
        """The regularized camera's image feature key."""
        cams = list(self.image_features)
        if not cams:
            raise GazeUsageError("gaze_camera", "the policy has no image features to regularize")
        cam = self.gaze_camera or cams[0]
        if cam not in cams:
            raise GazeUsageError(f"gaze_camera={cam}", f"not one of the policy's image features {cams}")
        return cam


def validate_gaze_options(cfg: Any) -> None:
    """Raise GazeUsageError (a ValueError) naming the first invalid gaze option of a gaze config."""
    if not (math.isfinite(cfg.gaze_weight) and cfg.gaze_weight >= 0):
        raise GazeUsageError("gaze_weight", f"must be a finite number >= 0, got {cfg.gaze_weight}")
    if cfg.gaze_target_mass is not None and not 0 < cfg.gaze_target_mass <= 1:
        raise GazeUsageError("gaze_target_mass", f"must be in (0, 1], got {cfg.gaze_target_mass}")
    if not cfg.gaze_sigma > 0:
        raise GazeUsageError(
            "gaze_sigma", f"must be > 0 (fraction of the frame height), got {cfg.gaze_sigma}"
        )
    if cfg.gaze_divergence not in DIVERGENCES:
        raise GazeUsageError(
            "gaze_divergence", f"must be forward, reverse or js, got {cfg.gaze_divergence!r}"
        )
    if cfg.gaze_key.startswith("observation."):
        raise GazeUsageError(
            f"gaze_key={cfg.gaze_key}",
            "the column is under observation.*, which LeRobot feeds to the policy as an input; store gaze under "
            "another prefix (e.g. gaze.point)",
        )
    if cfg._gaze_eager_only and cfg.gaze_weight > 0 and cfg.compile_model:
        raise GazeUsageError(
            "compile_model",
            "gaze regularization (gaze_weight > 0) captures attention in the eager forward and cannot run with "
            "compile_model: set it to false or gaze_weight=0",
        )


def check_gaze_features(cfg: Any, features: Mapping[str, Mapping[str, Any]]) -> None:
    """Raise GazeUsageError unless the data set's `features` (LeRobot's info.json features: key -> {dtype, shape,
    ...}) hold the gaze column `cfg.gaze_key` with a shape per frame gaze_targets.gaze_kind accepts, its flag
    column (where it has one) holds one bool per frame, and `cfg.gaze_camera` is one of the policy's image
    features. Nothing is checked when gaze_weight is 0 (the plain policy)."""
    if cfg.gaze_weight == 0:
        return
    key = cfg.gaze_key
    if key not in features:
        gaze_cols = sorted(k for k in features if k.startswith("gaze."))
        have = f"its gaze columns: {', '.join(gaze_cols)}" if gaze_cols else "it has no gaze.* column"
        raise GazeUsageError(f"gaze_key={key}", f"the data set has no such column ({have})")
    gaze_kind(key, tuple(features[key].get("shape") or ()))
    flag = gaze_valid_key(key)
    if flag is not None and flag in features:
        shape = tuple(int(d) for d in features[flag].get("shape") or (1,))
        if math.prod(shape) != 1:
            raise GazeUsageError(f"gaze_key={key}", f"its flag column {flag} has shape {shape}, not one bool")
    cfg.gaze_camera_key()


def check_gaze_layers(layers: Sequence[int] | None, valid: Sequence[int], model: str) -> None:
    """Raise GazeUsageError naming gaze_layers when `layers` (None: the default, nothing to check) is empty or
    holds an index not in `valid` (the layer indices the capture can regularize); `model` says what the model
    has, e.g. "the model has 18 layers, 0..17"."""
    if layers is None:
        return
    if not layers:
        raise GazeUsageError("gaze_layers", f"names no layer: {model}")
    bad = [int(i) for i in layers if i not in valid]
    if bad:
        raise GazeUsageError("gaze_layers", f"{bad} out of range: {model}")


INACTIVE_FRAMES_LIMIT = 1000


class GazeActivity:
    """Stops a gaze run whose term is never active: counts the training frames the gaze term saw and raises
    GazeUsageError once `limit` frames (over all batches so far, repeats counted) have gone by without a single
    usable one. After the first usable frame it checks nothing more. A training subset whose true fraction of
    usable frames is p is refused by mistake with probability (1 - p) ** limit (about 4e-5 for p = 0.01)."""

    def __init__(self, gaze_key: str, limit: int = INACTIVE_FRAMES_LIMIT):
        self.gaze_key = gaze_key
        self.limit = limit
        self.frames = 0
        self.active = False

    def update(self, valid: Tensor) -> None:
        """valid (B,) bool: the batch's frames with usable gaze."""
        if self.active:
            return
        if bool(valid.any()):
            self.active = True
            return
        self.frames += int(valid.numel())
        if self.frames >= self.limit:
            raise GazeUsageError(
                f"gaze_key={self.gaze_key}",
                f"none of the first {self.frames} training frames had usable gaze (gaze/valid_frac 0 at every "
                "step), so the gaze term was never active: the episodes trained on have no usable value in the "
                "column (NaN, outside the image, a heatmap <= 0 or flagged invalid); train on episodes with gaze "
                "or set --policy.gaze_weight=0",
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
    kl = across_processes(kl, valid)
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


class GazePolicy(Protocol):
    """What `finish_gaze_forward` reads from a gaze policy (smolvla_gaze, pi0_gaze, pi05_gaze)."""

    config: Any
    gaze_capture: Any  # a Capture whose image_tokens are those of the last captured forward
    _gaze_frame: tuple[int, ...] | None
    _gaze_activity: GazeActivity


def finish_gaze_forward(
    policy: GazePolicy,
    cam: str,
    cam_index: int,
    column: Tensor,
    flag: Tensor | None,
    geometry: tuple[PatchGeometry, bool, tuple[int, int]],
    loss: Tensor,
    loss_dict: dict[str, Any],
    reduction: str,
) -> tuple[Tensor, dict[str, Any]]:
    """The end of a gaze policy's training forward, after the base forward ran inside its capture: checks the
    camera's token count against `geometry` (token geometry, flip, stored (height, width)), turns the gaze
    `column` (B, *frame) and its `flag` (B,) bool or None into gaze distributions, counts the usable frames
    (GazeActivity) and returns add_gaze_term's (loss, loss dict)."""
    cfg = policy.config
    geom, flip, src_hw = geometry
    check_token_count(cam, policy.gaze_capture.image_tokens[cam_index], geom)
    with refusing():
        gaze, valid = gaze_distribution(
            column,
            geom,
            flip,
            cfg.gaze_sigma,
            src_hw,
            valid=flag,
            key=cfg.gaze_key,
            frame_shape=policy._gaze_frame,
        )
        policy._gaze_activity.update(valid)
    return add_gaze_term(cfg, policy.gaze_capture, loss, loss_dict, gaze, valid, reduction)
