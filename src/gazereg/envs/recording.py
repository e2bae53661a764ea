"""Recording a scripted rollout into an `Episode`: the simulator-independent loop.

    rec = record_rollout(env, act, seed=3, max_steps=200)    # any `gazereg.envs.interface.Env`
    ep = rec.episode(task, instruction, meta)

`record_rollout` drives an environment with the `gazereg.envs.interface.Env` API (MetaWorldEnv, LiberoEnv):
`reset(seed=)`, `step(action)`, `cameras`, `project(points, camera)`, and an `info` dict carrying `contact`,
`grasp`, `success` and world positions `<name>_pos` (obj, obj2, goal, hand).
Per frame t it keeps the observation before action t, and after the loop the extras
    <name>_pos (T, 3) float32 metres; <name>_uv.<camera> (T, 2) float32 normalised (u right, v down);
    contact, grasp, success (T,) bool; reward (T,) float32
which `gazereg collect` stores and the `visuomotor` gaze source reads. The experts' rollouts:
`gazereg.envs.metaworld.collector`, `gazereg.envs.libero.collector`.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from typing import Any

import numpy as np

from gazereg.data.store import Episode
from gazereg.envs.interface import Env

KEY_POINTS = ("obj", "obj2", "goal", "hand")


@dataclass
class Recording:
    """What one rollout saw and did: T steps, frames before each action."""

    frames: dict[str, np.ndarray]  # camera -> uint8 (T, H, W, 3)
    state: np.ndarray  # float32 (T, S)
    action: np.ndarray  # float32 (T, A)
    extras: dict[str, np.ndarray]  # see the module docstring
    success: bool
    seconds: float  # wall time of reset + rollout
    cpu_seconds: float  # this process's CPU time (renderer threads included)

    @property
    def length(self) -> int:
        return int(self.action.shape[0])

    def episode(self, task: str, instruction: str, meta: dict[str, Any]) -> Episode:
        """The episode to store: this recording's frames, state, action and extras with `meta`."""
        return Episode(
            task=task,
            instruction=instruction,
            frames=self.frames,
            state=self.state,
            action=self.action,
            extras=self.extras,
            meta=meta,
        )


def noise_seed(task: str, seed: int) -> list[int]:
    """The action-noise seed of (task, setup seed): the same in every process."""
    return [seed, int(hashlib.sha256(task.encode()).hexdigest()[:8], 16)]


def record_rollout(
    env: Env, act: Callable[[dict[str, Any], dict[str, Any]], np.ndarray], seed: int, max_steps: int
) -> Recording:
    """Reset `env` to setup `seed` and step it with `act(obs, info) -> action` until success or `max_steps`."""
    t0, c0 = time.perf_counter(), time.process_time()
    obs, info = env.reset(seed=seed)
    frames: dict[str, list[np.ndarray]] = {c: [] for c in env.cameras}
    states, actions, rewards, successes, contacts, grasps = [], [], [], [], [], []
    points: dict[str, list[np.ndarray]] = {}
    uvs: dict[str, list[np.ndarray]] = {}
    success = False
    for _ in range(max_steps):
        for c in env.cameras:
            frames[c].append(obs["images"][c])
        states.append(obs["state"])
        contacts.append(info["contact"])
        grasps.append(info["grasp"])
        for k in KEY_POINTS:
            if f"{k}_pos" in info:
                points.setdefault(k, []).append(info[f"{k}_pos"])
                for c in env.cameras:  # now: a camera on the wrist moves with the arm
                    uvs.setdefault(f"{k}_uv.{c}", []).append(env.project(info[f"{k}_pos"], c))
        action = act(obs, info)
        obs, reward, _, truncated, info = env.step(action)
        actions.append(action)
        rewards.append(reward)
        successes.append(info["success"])
        if info["success"]:
            success = True
            break
        if truncated:
            break
    extras: dict[str, np.ndarray] = {
        "contact": np.asarray(contacts, dtype=bool),
        "grasp": np.asarray(grasps, dtype=bool),
        "reward": np.asarray(rewards, dtype=np.float32),
        "success": np.asarray(successes, dtype=bool),
    }
    for k, seq in points.items():
        extras[f"{k}_pos"] = np.asarray(seq, dtype=np.float32)
    for k, seq in uvs.items():
        extras[k] = np.asarray(seq, dtype=np.float32)
    return Recording(
        frames={c: np.stack(frames[c]) for c in env.cameras},
        state=np.asarray(states, dtype=np.float32),
        action=np.asarray(actions, dtype=np.float32),
        extras=extras,
        success=success,
        seconds=time.perf_counter() - t0,
        cpu_seconds=time.process_time() - c0,
    )


def summary_of(task: str, seed: int, rec: Recording) -> dict[str, Any]:
    """The per-rollout summary `gazereg collect` logs (attempts.jsonl)."""
    return {
        "task": task,
        "seed": int(seed),
        "success": bool(rec.success),
        "steps": rec.length,
        "seconds": rec.seconds,
        "cpu_seconds": rec.cpu_seconds,  # this process, the renderer's threads included
    }


def versions(packages: Sequence[str]) -> dict[str, str]:
    """Installed versions of `packages` ("unknown" when not installed)."""
    out = {}
    for pkg in packages:
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "unknown"
    return out
