"""Configuration of the gaze-regularized SmolVLA (`--policy.type=smolvla_gaze`).

Every SmolVLA option is inherited unchanged; the gaze options are:

    --policy.gaze_weight=0.1             weight of KL(gaze || attention) added to the flow-matching loss
    --policy.gaze_key=gaze.point         the data set column holding the gaze (not under observation.*)
    --policy.gaze_camera=observation.images.front   the regularized camera (default: the first image feature)
    --policy.gaze_layers=[8,10,12,14]    VLM layer indices whose action-expert attention is regularized
                                         (default: the second half of the layers that have an expert layer)
    --policy.gaze_sigma=0.05             Gaussian sigma for point columns, as a fraction of the frame height
    --policy.gaze_divergence=forward     forward KL(gaze||attention) | reverse | js
"""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.configs import PreTrainedConfig
from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig


@PreTrainedConfig.register_subclass("smolvla_gaze")
@dataclass
class SmolVLAGazeConfig(SmolVLAConfig):
    gaze_weight: float = 0.1
    gaze_key: str = "gaze.point"
    gaze_camera: str | None = None
    gaze_layers: list[int] | None = None
    gaze_sigma: float = 0.05
    gaze_divergence: str = "forward"

    def __post_init__(self):
        super().__post_init__()
        if self.gaze_weight < 0:
            raise ValueError(f"gaze_weight must be >= 0, got {self.gaze_weight}")
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
