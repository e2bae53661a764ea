"""Configuration of the gaze-regularized pi0.5 (`--policy.type=pi05_gaze`): every pi05 option unchanged, plus
the gaze options of `pi0_gaze` (see configuration_pi0_gaze)."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.configs import PreTrainedConfig
from lerobot.policies.pi05.configuration_pi05 import PI05Config

from .configuration_pi0_gaze import check_gaze_options
from .configuration_smolvla_gaze import SmolVLAGazeConfig


@PreTrainedConfig.register_subclass("pi05_gaze")
@dataclass
class PI05GazeConfig(PI05Config):
    # Gaze: weight of KL(gaze || attention) added to pi05's flow-matching loss (0 = plain pi05).
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
