"""Configuration of the gaze-regularized pi0 (`--policy.type=pi0_gaze`).

Every pi0 option is inherited unchanged; the gaze options (gaze_common.GazeOptions) are those of `smolvla_gaze`:

    --policy.gaze_weight=0.1             weight of KL(gaze || attention) added to the flow-matching loss
    --policy.gaze_key=gaze.point         the data set column holding the gaze (not under observation.*)
    --policy.gaze_camera=observation.images.front   the regularized camera (default: the first image feature)
    --policy.gaze_layers=[9,11,13,15,17] layer indices (0..depth-1) whose action-token attention is regularized
                                         (default: the second half of the layers; every pi0 layer is joint)
    --policy.gaze_sigma=0.05             Gaussian sigma for point columns, as a fraction of the frame height
    --policy.gaze_divergence=forward     forward KL(gaze||attention) | reverse | js
    --policy.gaze_target_mass=0.5        mass variant: also pull the action tokens' attention mass on the camera's
                                         image tokens towards m in (0, 1] (default: off)

The attention is captured by wrapping the eager attention function during the training forward, so
`compile_model` is refused while gaze_weight > 0. `gradient_checkpointing` works: lerobot's pi0 checkpoints
its layers non-reentrantly, the capture runs in the first forward only and the probe keeps its own saved
tensors, so the recomputation in backward runs the plain layers and the gradient equals the one without
checkpointing (tests_lerobot/test_pi0_gaze.py).
"""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.configs import PreTrainedConfig
from lerobot.policies.pi0.configuration_pi0 import PI0Config

from .gaze_common import GazeOptions


@PreTrainedConfig.register_subclass("pi0_gaze")
@dataclass
class PI0GazeConfig(GazeOptions, PI0Config):
    """pi0's options plus the gaze options of `GazeOptions` (validated when the config is built)."""

    _gaze_eager_only = True
