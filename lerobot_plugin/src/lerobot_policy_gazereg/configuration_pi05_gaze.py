"""Configuration of the gaze-regularized pi0.5 (`--policy.type=pi05_gaze`): every pi05 option unchanged, plus
the gaze options of `pi0_gaze` (gaze_common.GazeOptions; see configuration_pi0_gaze)."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.configs import PreTrainedConfig
from lerobot.policies.pi05.configuration_pi05 import PI05Config

from .gaze_common import GazeOptions


@PreTrainedConfig.register_subclass("pi05_gaze")
@dataclass
class PI05GazeConfig(GazeOptions, PI05Config):
    """pi0.5's options plus the gaze options of `GazeOptions` (validated when the config is built)."""

    _gaze_eager_only = True
