"""gazereg's LeRobot plugin: `--policy.type=smolvla_gaze`, `pi0_gaze` and `pi05_gaze`: SmolVLA, pi0 and pi0.5
trained with gaze regularization.

Installed next to lerobot, this distribution (named `lerobot_policy_gazereg`) is imported by LeRobot's
`register_third_party_plugins()` at the start of lerobot-train / lerobot-eval, which registers the policy types
(no fork, no copied modeling code: SmolVLAPolicy / PI0Policy / PI05Policy are subclassed and their attention
wrapped at run time).

    lerobot-train --policy.type=smolvla_gaze --policy.gaze_weight=0.1 --policy.gaze_key=gaze.point \
        --policy.gaze_camera=observation.images.front --dataset.repo_id=... --dataset.root=...
"""

from .configuration_pi0_gaze import PI0GazeConfig
from .configuration_pi05_gaze import PI05GazeConfig
from .configuration_smolvla_gaze import SmolVLAGazeConfig

__all__ = ["PI0GazeConfig", "PI05GazeConfig", "SmolVLAGazeConfig"]
__version__ = "0.1.0"
