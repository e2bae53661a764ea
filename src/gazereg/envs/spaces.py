"""The gymnasium spaces every `gazereg.envs.interface.Env` declares (this module imports gymnasium)."""

from __future__ import annotations

import string

import gymnasium as gym
import numpy as np


def env_spaces(
    cameras: tuple[str, ...], height: int, width: int, state_dim: int, action_dim: int
) -> tuple[gym.spaces.Dict, gym.spaces.Box]:
    """(observation space, action space): images uint8 (height, width, 3) per camera, state float32
    (state_dim,), an instruction of up to 512 printable characters; actions float32 (action_dim,) in [-1, 1]."""
    image_spaces = {c: gym.spaces.Box(0, 255, (height, width, 3), dtype=np.uint8) for c in cameras}
    observation_space = gym.spaces.Dict(
        {
            "images": gym.spaces.Dict(image_spaces),
            "state": gym.spaces.Box(-np.inf, np.inf, (state_dim,), dtype=np.float32),
            "instruction": gym.spaces.Text(max_length=512, charset=string.printable),
        }
    )
    return observation_space, gym.spaces.Box(-1.0, 1.0, (action_dim,), dtype=np.float32)
