"""What evaluation and collection need from a simulator: the `Env` and `Collector` protocols, and the
argument checks every environment shares (`image_hw`, `check_cameras`, `check_render_mode`).

Simulators implement these (`gazereg.envs.metaworld`, `gazereg.envs.libero`); `gazereg.envs.base` registers
them by name. This module names no simulator, so an implementation importing it closes no import loop
with the registry, which names the implementations' modules as "module:Class" strings.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from gazereg.data.store import Episode
from gazereg.envs.camera import CameraGeometry
from gazereg.envs.perturbations import Perturbation


class Env(Protocol):
    """A simulated task with RGB cameras, proprioception and an instruction (gymnasium's reset/step API).

    Constructor: `Env(task, cameras=, image_size=, max_steps=, perturbation=, gl_backend=)`.

    Observations: {"images": {camera: uint8 (H, W, 3) upright, as the policy sees it}, "state": float32 (S,),
    "instruction": str}. `reset(seed=s)` starts setup seed `s` (the simulator fixes the scene from it; the same
    seed gives the same setup in any process). `info` after reset and every step: success (bool), setup_seed,
    steps, contact and grasp (bool), world positions `<name>_pos` (3,) in metres (obj, goal, hand, maybe obj2)
    and, where the simulator measures it, `obj_to_target`: the object's (or hand's) distance to its target
    in metres."""

    task: str
    cameras: tuple[str, ...]
    image_size: tuple[int, int]
    max_steps: int
    fps: float
    instruction: str

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]: ...

    def step(self, action: np.ndarray) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]: ...

    def render_images(self) -> dict[str, np.ndarray]: ...

    def camera_geometry(self, camera: str) -> CameraGeometry: ...

    def project(self, points: np.ndarray, camera: str) -> np.ndarray:
        """World points (..., 3) -> normalised (u right, v down) (..., 2) in `camera`'s image as returned."""
        ...

    def key_points(self) -> dict[str, np.ndarray]: ...

    def contact_state(self) -> tuple[bool, bool]: ...

    @property
    def perturbation(self) -> Perturbation: ...

    def set_perturbation(self, perturbation: Perturbation | None) -> None: ...

    def close(self) -> None: ...


class Collector(Protocol):
    """A simulator's scripted expert for `gazereg collect`: tasks, its environments and one rollout."""

    name: str
    default_cameras: tuple[str, ...]
    default_max_steps: int
    max_steps_limit: int

    def tasks(self, requested: Sequence[str]) -> tuple[str, ...]:
        """Canonical task names (suites expanded); ValueError or KeyError naming the unknown ones."""
        ...

    def episode_task(self, task: str) -> str:
        """The `task` an episode of `task` is stored under."""
        ...

    def instruction(self, task: str) -> str:
        """The instruction an episode of `task` stores (known without a rollout)."""
        ...

    def make_env(self, task: str, cfg: Any) -> Env:
        """The environment of `task` with the render settings of `cfg` (a resolved CollectConfig)."""
        ...

    def rollout(
        self, env: Env, seed: int, action_noise: float, max_steps: int
    ) -> tuple[Episode, dict[str, Any]]:
        """The expert on setup `seed`: the episode (also when it failed) and its summary (task, seed, success,
        steps, seconds, cpu_seconds)."""
        ...


def image_hw(image_size: int | Sequence[int]) -> tuple[int, int]:
    """An image size (side, or (height, width)) as positive (height, width) pixels; ValueError otherwise."""
    H, W = (image_size, image_size) if isinstance(image_size, int) else tuple(image_size)
    if H <= 0 or W <= 0:
        raise ValueError(f"image size must be positive, got {image_size}")
    return int(H), int(W)


def check_cameras(cameras: Sequence[str]) -> tuple[str, ...]:
    """Camera names as a tuple; ValueError for duplicates."""
    cams = tuple(cameras)
    if len(set(cams)) != len(cams):
        raise ValueError(f"duplicate cameras in {cams}")
    return cams


def check_render_mode(render_mode: str | None) -> None:
    if render_mode not in (None, "rgb_array"):
        raise ValueError(f"render_mode must be 'rgb_array' or None, got {render_mode!r}")
