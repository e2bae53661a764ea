"""A toy simulator, a toy gaze source and a toy arm, as a third-party package would ship them: nothing in
gazereg names them; tests/plugins/test_plugin_registries.py declares them in the entry-point groups
`gazereg.simulators`, `gazereg.gaze_sources` and `gazereg.arms` (or registers them in code).

The toy simulator's tasks move a dot across a grey image: `dot-left` and `dot-right`, each rollout a few steps
that always succeed. The toy gaze source looks at a fixed column; the toy arm trains on it and is a control."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from gazereg.data.store import Episode
from gazereg.envs.base import Simulator
from gazereg.gaze.sources import register_gaze_source
from gazereg.gaze.sources.params import GazeSourceParams
from gazereg.training.arms import Arm, PriorSpec

TASKS = ("dot-left", "dot-right")


class ToyEnv:
    """Just enough of `gazereg.envs.base.Env` for a collection: an image of a dot, a 2-D state."""

    fps = 10.0

    def __init__(
        self, task: str, cameras: tuple[str, ...] = ("cam",), image_size: int = 16, max_steps: int = 5
    ):
        self.task, self.cameras, self.max_steps = task, cameras, max_steps
        self.image_size = (image_size, image_size)
        self.instruction = ToyCollector().instruction(task)
        self.x = 0.5

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        self.x = 0.25 + 0.5 * ((seed or 0) % 5) / 4
        return self.observation(), {"success": False}

    def step(self, action: np.ndarray):
        self.x = float(np.clip(self.x + 0.1 * float(action[0]), 0.0, 1.0))
        return self.observation(), 0.0, False, False, {"success": True}

    def observation(self) -> dict[str, Any]:
        return {"images": self.render_images(), "state": np.array([self.x, 0.5], np.float32)}

    def render_images(self) -> dict[str, np.ndarray]:
        h, w = self.image_size
        img = np.full((h, w, 3), 128, np.uint8)
        img[h // 2, min(int(self.x * w), w - 1)] = 255
        return {c: img.copy() for c in self.cameras}

    def close(self) -> None:
        pass


class ToyCollector:
    """`gazereg collect --env toy`: the dot moves toward its side for `max_steps` steps and always succeeds."""

    name = "toy"
    default_cameras = ("cam",)
    default_max_steps = 4
    max_steps_limit = 10

    def tasks(self, requested: Sequence[str]) -> tuple[str, ...]:
        unknown = [t for t in requested if t not in TASKS]
        if unknown:
            raise ValueError(f"unknown toy tasks {unknown}; the toy simulator has {list(TASKS)}")
        return tuple(requested)

    def episode_task(self, task: str) -> str:
        return task

    def instruction(self, task: str) -> str:
        return f"move the dot {task.split('-')[1]}"

    def make_env(self, task: str, cfg: Any) -> ToyEnv:
        return ToyEnv(task, tuple(cfg.cameras), cfg.image_size, cfg.max_steps)

    def rollout(self, env: ToyEnv, seed: int, action_noise: float, max_steps: int) -> tuple[Episode, dict]:
        t0 = time.perf_counter()
        obs, _ = env.reset(seed=seed)
        direction = -1.0 if env.task.endswith("left") else 1.0
        frames, states, actions = [], [], []
        for _ in range(max_steps):
            action = np.array([direction, 0.0], np.float32)
            frames.append(obs["images"])
            states.append(obs["state"])
            actions.append(action)
            obs, *_ = env.step(action)
        episode = Episode(
            task=env.task,
            instruction=env.instruction,
            frames={c: np.stack([f[c] for f in frames]) for c in env.cameras},
            state=np.stack(states),
            action=np.stack(actions),
            meta={"seed": int(seed), "success": True, "fps": env.fps, "env": "toy", "steps": max_steps},
        )
        seconds = time.perf_counter() - t0
        summary = {"task": env.task, "seed": seed, "success": True, "steps": max_steps, "seconds": seconds}
        return episode, {**summary, "cpu_seconds": seconds}


SIMULATOR = Simulator("toy", env="toy_plugins:ToyEnv", collector="toy_plugins:ToyCollector")


@dataclass(frozen=True)
class ToyGazeParams(GazeSourceParams):
    """The toy source looks at column `column` (0 left .. 1 right) of the middle row in every frame."""

    name: ClassVar[str] = "toy"
    column: float = 0.5


@register_gaze_source(ToyGazeParams)
class ToyGaze:
    name = "toy"

    def __init__(self, params: ToyGazeParams):
        self.params = params

    def __call__(self, episode: Episode, camera: str, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        h, w = size
        heat = np.zeros((episode.length, h, w), np.float32)
        heat[:, h // 2, min(int(self.params.column * w), w - 1)] = 1.0
        return heat, np.ones(episode.length, bool)

    def describe(self) -> dict[str, Any]:
        return {"name": "toy", "column": self.params.column}


ARM = Arm(
    "toy",
    prior=lambda cfg, task_names: PriorSpec("toy", ToyGazeParams(column=0.25)),
    control=True,
    description="the toy source's fixed column: a control",
)
