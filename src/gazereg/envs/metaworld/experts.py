"""Meta-World's own scripted expert policies (`metaworld.policies`), with optional seeded action noise.

The experts read Meta-World's flat 39-d observation (hand position, gripper opening, object poses, goal),
which `MetaWorldEnv` exposes as `info["raw_obs"]` / `env.raw_obs`; they never see images.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np


def expert_policy(task: str) -> Any:
    """Meta-World's scripted policy for `task` (an object with `get_action(raw_obs) -> (4,) action`)."""
    from metaworld.policies import ENV_POLICY_MAP

    if task not in ENV_POLICY_MAP:
        raise KeyError(f"Meta-World has no scripted expert for {task!r}; tasks: {sorted(ENV_POLICY_MAP)}")
    return ENV_POLICY_MAP[task]()


class Expert:
    """A scripted expert whose actions get Gaussian noise of std `noise` (in action units, range [-1, 1]).

    The noise generator is seeded from `seed`, so an episode (setup seed + noise seed) replays exactly.
    """

    def __init__(self, task: str, noise: float = 0.0, seed: int = 0):
        if noise < 0:
            raise ValueError(f"action noise must be >= 0, got {noise}")
        self.task = task
        self.noise = float(noise)
        self.policy = expert_policy(task)
        self.rng = np.random.default_rng(seed)

    @property
    def name(self) -> str:
        cls = type(self.policy)
        return f"{cls.__module__}.{cls.__qualname__}"

    def reset(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def __call__(self, raw_obs: np.ndarray) -> np.ndarray:
        with warnings.catch_warnings():
            # The experts warn when their proportional gains saturate; the env clips actions anyway.
            warnings.simplefilter("ignore", UserWarning)
            action = np.asarray(self.policy.get_action(raw_obs), dtype=np.float64)
        if self.noise > 0:
            action = action + self.rng.normal(0.0, self.noise, size=action.shape)
        return np.clip(action, -1.0, 1.0).astype(np.float32)
