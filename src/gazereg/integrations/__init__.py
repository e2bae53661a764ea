"""Gaze regularization for existing VLA frameworks, without forking them.

- `gazereg.integrations.transformers`: transformers' PI0, PaliGemma, Idefics3 / SmolVLM and Llava
  (`GazeRegularizer`, `camera_geometry`), and models without an image token id (OpenVLA-style patches after
  BOS: `inserted_patch_family`, `register_family`, or `patch_positions=`). Needs the `hf` extra
  (transformers >= 5); importing this package does not import transformers, which loads when a regularizer is
  built.
- LeRobot: the separate `lerobot_policy_gazereg` plugin distribution (lerobot_plugin/ in the repository).
"""

from gazereg.integrations.transformers import (
    GazeRegularizer,
    camera_geometry,
    inserted_patch_family,
    register_family,
    register_gaze_attention,
)

__all__ = [
    "GazeRegularizer",
    "camera_geometry",
    "inserted_patch_family",
    "register_family",
    "register_gaze_attention",
]
