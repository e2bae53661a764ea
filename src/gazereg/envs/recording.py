"""Recording a scripted rollout into an `Episode`: the simulator-independent loop and Meta-World's experts.

    rec = record_rollout(env, act, seed=3, max_steps=200)    # any env with the MetaWorldEnv API
    ep, summary = rollout_expert(env, seed=3)                # Meta-World's scripted expert on setup 3

`record_rollout` drives an environment with the API of `gazereg.envs.metaworld.env.MetaWorldEnv` (also
`gazereg.envs.libero.env.LiberoEnv`): `reset(seed=)`, `step(action)`, `cameras`, `project(points, camera)`, and an
`info` dict carrying `contact`, `grasp`, `success` and world positions `<name>_pos` (obj, obj2, goal, hand).
Per frame t it keeps the observation before action t, and after the loop the extras
    <name>_pos (T, 3) float32 metres; <name>_uv.<camera> (T, 2) float32 normalised (u right, v down);
    contact, grasp, success (T,) bool; reward (T,) float32
which `gazereg collect` stores and the `visuomotor` gaze source reads. The LIBERO expert's rollout lives in
`gazereg.envs.libero.expert`.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from gazereg.data.store import Episode

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
    env: Any, act: Callable[[dict[str, Any], dict[str, Any]], np.ndarray], seed: int, max_steps: int
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
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for pkg in packages:
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "unknown"
    return out


def rollout_expert(
    env: Any, seed: int, action_noise: float = 0.0, max_steps: int | None = None, expert: Any = None
) -> tuple[Episode, dict[str, Any]]:
    """Roll Meta-World's scripted expert out on setup `seed` of `env` (a MetaWorldEnv).

    Returns the episode (also when it failed: meta["success"] says) and a summary dict.
    """
    from gazereg.envs.metaworld.env import ACTION_LAYOUT, STATE_LAYOUT, setup_of
    from gazereg.envs.metaworld.experts import Expert

    task = env.task
    expert = expert or Expert(task, noise=action_noise)
    expert.reset(noise_seed(task, seed))
    rec = record_rollout(env, lambda obs, info: expert(env.raw_obs), seed, max_steps or env.max_steps)
    b, k = setup_of(seed)
    meta = {
        "seed": int(seed),
        "setup": {"benchmark": "metaworld.MT1", "benchmark_seed": b, "index": k},
        "success": bool(rec.success),
        "fps": float(env.fps),
        "env": "metaworld",
        "env_name": task,
        "steps": rec.length,
        "expert": expert.name,
        "action_noise": float(action_noise),
        "camera_geometry": {c: env.camera_geometry(c).to_dict() for c in env.cameras},
        "goal_marker_radius": float(env.goal_marker_radius),
        "state_layout": list(STATE_LAYOUT),
        "action_layout": list(ACTION_LAYOUT),
        "versions": versions(("metaworld", "mujoco", "gazereg")),
    }
    return rec.episode(task, env.instruction, meta), summary_of(task, seed, rec)


class MetaWorldCollector:
    """`gazereg collect --env metaworld`: Meta-World v3 tasks rolled out by Meta-World's scripted experts."""

    name = "metaworld"
    default_cameras = ("corner2",)
    default_max_steps = 200

    @property
    def max_steps_limit(self) -> int:
        from gazereg.envs.metaworld.env import MAX_PATH_LENGTH

        return MAX_PATH_LENGTH

    def tasks(self, requested: Sequence[str]) -> tuple[str, ...]:
        """Validated task names (unchanged); ValueError names the unknown ones."""
        from gazereg.envs.metaworld.env import meta_world_tasks

        known = set(meta_world_tasks())
        bad = [t for t in requested if t not in known]
        if bad:
            raise ValueError(f"unknown Meta-World task(s) {bad}; v3 tasks: {', '.join(sorted(known))}")
        return tuple(requested)

    def episode_task(self, task: str) -> str:
        """The `task` an episode of `task` is stored under."""
        return task

    def make_env(self, task: str, cfg: Any) -> Any:
        from gazereg.envs.metaworld.env import MetaWorldEnv
        from gazereg.envs.perturbations import parse_perturbation

        return MetaWorldEnv(
            task,
            cameras=cfg.cameras,
            image_size=cfg.image_size,
            max_steps=cfg.max_steps,
            goal_marker_radius=cfg.goal_marker_radius,
            gl_backend=cfg.gl_backend or None,
            perturbation=parse_perturbation(cfg.perturbation),
        )

    def rollout(
        self, env: Any, seed: int, action_noise: float, max_steps: int
    ) -> tuple[Episode, dict[str, Any]]:
        return rollout_expert(env, seed, action_noise=action_noise, max_steps=max_steps)
