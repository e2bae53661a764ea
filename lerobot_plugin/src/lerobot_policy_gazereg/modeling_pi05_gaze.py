"""pi0.5 with gaze regularization: PI05Policy unchanged, plus the gaze term of `pi0_gaze` (see
modeling_pi0_gaze): the attention of the expert's action tokens (pi0.5's whole suffix; the state is tokenized
in the prefix) to one camera's image tokens."""

from __future__ import annotations

from typing import Any

from lerobot.policies.pi05 import modeling_pi05
from lerobot.policies.pi05.modeling_pi05 import PI05Policy

from .configuration_pi05_gaze import PI05GazeConfig
from .modeling_pi0_gaze import PiGazeMixin


class PI05GazePolicy(PiGazeMixin, PI05Policy):
    config_class = PI05GazeConfig
    name = "pi05_gaze"
    _lerobot_modeling = modeling_pi05

    def __init__(self, config: PI05GazeConfig, **kwargs: Any):
        self._check_before_build(config, kwargs.get("dataset_meta"))  # before PaliGemma (and its weights)
        super().__init__(config, **kwargs)
        self._init_gaze(kwargs)
