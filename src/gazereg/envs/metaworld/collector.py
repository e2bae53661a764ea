"""Meta-World demonstrations: its scripted experts rolled out into episodes (`gazereg collect --env metaworld`).

    ep, summary = rollout_expert(env, seed=3)     # Meta-World's expert on setup 3 of a MetaWorldEnv

The episode holds what `gazereg.envs.recording.record_rollout` records, with meta: seed, setup (MT1 benchmark
seed and index), success, fps, env, env_name, steps, expert, action_noise, camera geometry, goal marker radius,
state and action layouts, package versions.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from gazereg.data.store import Episode
from gazereg.envs.metaworld.env import (
    ACTION_LAYOUT,
    MAX_PATH_LENGTH,
    STATE_LAYOUT,
    MetaWorldEnv,
    meta_world_tasks,
    setup_of,
)
from gazereg.envs.metaworld.experts import Expert
from gazereg.envs.metaworld.instructions import instruction_for
from gazereg.envs.perturbations import parse_perturbation
from gazereg.envs.recording import noise_seed, record_rollout, summary_of, versions


def rollout_expert(
    env: MetaWorldEnv,
    seed: int,
    action_noise: float = 0.0,
    max_steps: int | None = None,
    expert: Expert | None = None,
) -> tuple[Episode, dict[str, Any]]:
    """Roll Meta-World's scripted expert out on setup `seed` of `env`.

    Returns the episode (also when it failed: meta["success"] says) and a summary dict.
    """
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
    max_steps_limit = MAX_PATH_LENGTH

    def tasks(self, requested: Sequence[str]) -> tuple[str, ...]:
        """Validated task names (unchanged); ValueError names the unknown ones."""
        known = set(meta_world_tasks())
        bad = [t for t in requested if t not in known]
        if bad:
            raise ValueError(f"unknown Meta-World task(s) {bad}; v3 tasks: {', '.join(sorted(known))}")
        return tuple(requested)

    def episode_task(self, task: str) -> str:
        return task

    def instruction(self, task: str) -> str:
        return instruction_for(task)

    def make_env(self, task: str, cfg: Any) -> MetaWorldEnv:
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
        self, env: MetaWorldEnv, seed: int, action_noise: float, max_steps: int
    ) -> tuple[Episode, dict[str, Any]]:
        return rollout_expert(env, seed, action_noise=action_noise, max_steps=max_steps)
