"""Configuration of the gaze-regularized SmolVLA (`--policy.type=smolvla_gaze`).

Every SmolVLA option is inherited unchanged; the gaze options (gaze_common.GazeOptions) are:

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

from dataclasses import dataclass

from lerobot.configs import PreTrainedConfig
from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig

from .gaze_common import GazeOptions


@PreTrainedConfig.register_subclass("smolvla_gaze")
@dataclass
class SmolVLAGazeConfig(GazeOptions, SmolVLAConfig):
    """SmolVLA's options plus the gaze options of `GazeOptions` (validated when the config is built)."""
