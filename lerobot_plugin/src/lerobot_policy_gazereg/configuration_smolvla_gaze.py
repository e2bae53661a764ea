"""Configuration of the gaze-regularized SmolVLA (`--policy.type=smolvla_gaze`).

Every SmolVLA option is inherited unchanged; the gaze options are:

    --policy.gaze_weight=0.1             weight of KL(gaze || attention) added to the flow-matching loss
    --policy.gaze_key=gaze.point         the data set column holding the gaze (not under observation.*)
    --policy.gaze_camera=observation.images.front   the regularized camera (default: the first image feature)
    --policy.gaze_layers=[8,10,12,14]    VLM layer indices whose action-expert attention is regularized
                                         (default: the second half of the layers that have an expert layer)
    --policy.gaze_sigma=0.05             Gaussian sigma for point columns, as a fraction of the frame height
    --policy.gaze_divergence=forward     forward KL(gaze||attention) | reverse | js
    --policy.gaze_target_mass=0.5        mass variant: also pull the action tokens' attention mass on the camera's
                                         image tokens towards m in (0, 1] (KL over the image tokens plus one
                                         non-image bin); default: the plain KL over the renormalised attention
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lerobot.configs import PreTrainedConfig
from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig


@PreTrainedConfig.register_subclass("smolvla_gaze")
@dataclass
class SmolVLAGazeConfig(SmolVLAConfig):
    """SmolVLA's options plus the gaze options below; the comment above each gaze field is its help text in
    `lerobot-train --policy.type=smolvla_gaze --help` (draccus reads it from this source)."""

    # Gaze: weight of KL(gaze || attention) added to SmolVLA's flow-matching loss (0 = plain SmolVLA).
    gaze_weight: float = 0.1
    # Gaze: the data set column holding the gaze, e.g. gaze.point (never under observation.*).
    gaze_key: str = "gaze.point"
    # Gaze: the regularized camera's image feature key (default: the policy's first image feature).
    gaze_camera: str | None = None
    # Gaze: VLM layer indices whose action-expert attention is regularized (default: the second half).
    gaze_layers: list[int] | None = None
    # Gaze: Gaussian sigma for (u, v) point columns, as a fraction of the frame height.
    gaze_sigma: float = 0.05
    # Gaze: the divergence, forward KL(gaze||attention) | reverse | js.
    gaze_divergence: str = "forward"
    # Gaze: mass variant, pull the attention mass on the camera's image tokens towards m in (0, 1] (default: off).
    gaze_target_mass: float | None = None

    def __post_init__(self):
        super().__post_init__()
        if not (math.isfinite(self.gaze_weight) and self.gaze_weight >= 0):
            raise ValueError(f"gaze_weight must be a finite number >= 0, got {self.gaze_weight}")
        if self.gaze_target_mass is not None and not 0 < self.gaze_target_mass <= 1:
            raise ValueError(f"gaze_target_mass must be in (0, 1], got {self.gaze_target_mass}")
        if not self.gaze_sigma > 0:
            raise ValueError(f"gaze_sigma must be > 0 (fraction of the frame height), got {self.gaze_sigma}")
        if self.gaze_divergence not in ("forward", "reverse", "js"):
            raise ValueError(f"gaze_divergence must be forward, reverse or js, got {self.gaze_divergence!r}")
        if self.gaze_key.startswith("observation."):
            raise ValueError(
                f"gaze_key {self.gaze_key!r} is under observation.*, which LeRobot feeds to the policy as an "
                "input; store gaze under another prefix (e.g. gaze.point)"
            )

    def gaze_camera_key(self) -> str:
        """The regularized camera's image feature key."""
        cams = list(self.image_features)
        if not cams:
            raise ValueError("the policy has no image features to regularize")
        cam = self.gaze_camera or cams[0]
        if cam not in cams:
            raise ValueError(f"gaze_camera {cam!r} is not one of the policy's image features {cams}")
        return cam
