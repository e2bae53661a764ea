"""gazereg's LeRobot plugin: `--policy.type=smolvla_gaze`, SmolVLA trained with gaze regularization.

Installed next to lerobot, this distribution (named `lerobot_policy_gazereg`) is imported by LeRobot's
`register_third_party_plugins()` at the start of lerobot-train / lerobot-eval, which registers the policy type
(no fork, no copied modeling code: SmolVLAPolicy is subclassed and its attention wrapped at run time).

    lerobot-train --policy.type=smolvla_gaze --policy.gaze_weight=0.1 --policy.gaze_key=gaze.point \
        --policy.gaze_camera=observation.images.front --dataset.repo_id=... --dataset.root=...
"""

from .configuration_smolvla_gaze import SmolVLAGazeConfig

__all__ = ["SmolVLAGazeConfig"]
__version__ = "0.1.0"
