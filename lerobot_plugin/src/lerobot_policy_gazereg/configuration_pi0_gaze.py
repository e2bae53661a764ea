"""Configuration of the gaze-regularized pi0 (`--policy.type=pi0_gaze`).

Every pi0 option is inherited unchanged; the gaze options are those of `smolvla_gaze`:

    --policy.gaze_weight=0.1             weight of KL(gaze || attention) added to the flow-matching loss
    --policy.gaze_key=gaze.point         the data set column holding the gaze (not under observation.*)
    --policy.gaze_camera=observation.images.front   the regularized camera (default: the first image feature)
    --policy.gaze_layers=[9,11,13,15,17] layer indices (0..depth-1) whose action-token attention is regularized
                                         (default: the second half of the layers; every pi0 layer is joint)
    --policy.gaze_sigma=0.05             Gaussian sigma for point columns, as a fraction of the frame height
    --policy.gaze_divergence=forward     forward KL(gaze||attention) | reverse | js

The attention is captured by wrapping the eager attention function during the training forward, so
`gradient_checkpointing` (which recomputes the layers in backward) and `compile_model` are refused while
gaze_weight > 0.
"""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.configs import PreTrainedConfig
from lerobot.policies.pi0.configuration_pi0 import PI0Config

from .configuration_smolvla_gaze import SmolVLAGazeConfig


def check_gaze_options(cfg: PreTrainedConfig) -> None:
    """Raise ValueError naming the first invalid gaze option of a pi0/pi05 gaze config."""
    if cfg.gaze_weight < 0:
        raise ValueError(f"gaze_weight must be >= 0, got {cfg.gaze_weight}")
    if not cfg.gaze_sigma > 0:
        raise ValueError(f"gaze_sigma must be > 0 (fraction of the frame height), got {cfg.gaze_sigma}")
    if cfg.gaze_divergence not in ("forward", "reverse", "js"):
        raise ValueError(f"gaze_divergence must be forward, reverse or js, got {cfg.gaze_divergence!r}")
    if cfg.gaze_key.startswith("observation."):
        raise ValueError(
            f"gaze_key {cfg.gaze_key!r} is under observation.*, which LeRobot feeds to the policy as an "
            "input; store gaze under another prefix (e.g. gaze.point)"
        )
    if cfg.gaze_weight > 0 and (cfg.gradient_checkpointing or cfg.compile_model):
        raise ValueError(
            "gaze regularization (gaze_weight > 0) captures attention in the eager forward and cannot run with "
            "gradient_checkpointing or compile_model: set them to false or gaze_weight=0"
        )


@PreTrainedConfig.register_subclass("pi0_gaze")
@dataclass
class PI0GazeConfig(PI0Config):
    # Gaze: weight of KL(gaze || attention) added to pi0's flow-matching loss (0 = plain pi0).
    gaze_weight: float = 0.1
    # Gaze: the data set column holding the gaze, e.g. gaze.point (never under observation.*).
    gaze_key: str = "gaze.point"
    # Gaze: the regularized camera's image feature key (default: the policy's first image feature).
    gaze_camera: str | None = None
    # Gaze: layer indices (0..depth-1) whose action-token attention is regularized (default: the second half).
    gaze_layers: list[int] | None = None
    # Gaze: Gaussian sigma for (u, v) point columns, as a fraction of the frame height.
    gaze_sigma: float = 0.05
    # Gaze: the divergence, forward KL(gaze||attention) | reverse | js.
    gaze_divergence: str = "forward"

    def __post_init__(self):
        super().__post_init__()
        check_gaze_options(self)

    gaze_camera_key = SmolVLAGazeConfig.gaze_camera_key
