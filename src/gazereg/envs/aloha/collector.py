"""Gym-Aloha demonstrations: `AlohaExpert` rolled out into episodes (`gazereg collect --env aloha`).

    ep, summary = rollout_aloha_expert(env, seed=3)     # on setup 3 of an AlohaEnv

The episode's task is the LeRobot task name (`AlohaTransferCube-v0`, `AlohaInsertion-v0`); besides what
`gazereg.envs.recording.record_rollout` records (obj/obj2/goal/hand positions and their `_uv.<camera>`,
contact, grasp, success, reward) it holds per frame
    contact.obj   bool (T,): the right gripper touches obj (the cube; the peg)
    contact.obj2  bool (T,): insertion only, the left gripper touches the socket
    left_hand_pos, right_hand_pos  float32 (T, 3): the grasp points, metres
and meta["gaze_targets"]: the targets the `visuomotor` gaze source visits in order ("obj", "goal" for the
transfer: the cube, then the hand-over point; "obj", "obj2", "goal" for the insertion: peg, socket, the
meeting point), with the rest of the meta the other simulators store. Importing this module does not import
gym-aloha.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from gazereg.data.store import Episode
from gazereg.envs.aloha.env import ACTION_LAYOUT, STATE_LAYOUT, AlohaEnv
from gazereg.envs.aloha.expert import AlohaExpert
from gazereg.envs.aloha.setup import EPISODE_LENGTH, TASKS, aloha_available, resolve_task
from gazereg.envs.perturbations import parse_perturbation
from gazereg.envs.recording import noise_seed, record_rollout, summary_of, versions

GAZE_TARGETS = {"transfer_cube": ("obj", "goal"), "insertion": ("obj", "obj2", "goal")}


def rollout_aloha_expert(
    env: AlohaEnv,
    seed: int,
    action_noise: float = 0.0,
    max_steps: int | None = None,
    expert: AlohaExpert | None = None,
) -> tuple[Episode, dict[str, Any]]:
    """Roll the bimanual expert out on setup `seed` of `env`.

    Returns the Episode (also when it failed: meta["success"] says) and the summary `gazereg collect` logs."""
    expert = expert or AlohaExpert(noise=action_noise)
    per_frame: dict[str, list[Any]] = {}

    def act(obs: dict[str, Any], info: dict[str, Any]) -> np.ndarray:
        if not per_frame:  # the env has just been reset by record_rollout
            expert.reset(env, noise_seed(env.task, seed))
        for k in ("contact.obj", "contact.obj2", "left_hand_pos", "right_hand_pos"):
            if k in info:
                per_frame.setdefault(k, []).append(info[k])
        return expert(env)

    rec = record_rollout(env, act, seed, max_steps or env.max_steps)
    for k, seq in per_frame.items():
        rec.extras[k] = np.asarray(seq, dtype=bool if k.startswith("contact") else np.float32)
    spec = env.spec_task
    meta = {
        "seed": int(seed),
        "setup": {"benchmark": "gym_aloha", "task": spec.name, "seed": int(seed)},
        "success": bool(rec.success),
        "fps": float(env.fps),
        "env": "aloha",
        "env_name": spec.name,
        "steps": rec.length,
        "expert": expert.name,
        "action_noise": float(action_noise),
        "gaze_targets": list(GAZE_TARGETS[spec.gym_task]),
        "camera_geometry": {c: env.camera_geometry(c).to_dict() for c in env.cameras},
        "state_layout": list(STATE_LAYOUT),
        "action_layout": list(ACTION_LAYOUT),
        "versions": versions(("gym-aloha", "dm-control", "mujoco", "gazereg")),
    }
    return rec.episode(spec.name, env.instruction, meta), summary_of(spec.name, seed, rec)


class AlohaCollector:
    """`gazereg collect --env aloha`: Gym-Aloha's two tasks rolled out by `AlohaExpert`; seed s is gym-aloha's
    setup s (`setup.sample_setup`)."""

    name = "aloha"
    default_cameras = ("top",)
    default_max_steps = EPISODE_LENGTH
    max_steps_limit = 10_000

    def tasks(self, requested: Sequence[str]) -> tuple[str, ...]:
        """Canonical task names (`aloha` expands to both); ValueError naming the unknown ones or gym-aloha missing."""
        ok, why = aloha_available()
        if not ok:
            raise ValueError(f"--env aloha: {why}")
        out: list[str] = []
        for spec in requested:
            if spec == "aloha":
                out += list(TASKS)
                continue
            try:
                out.append(resolve_task(spec).name)
            except KeyError as e:
                raise ValueError(str(e.args[0])) from None
        return tuple(out)

    def episode_task(self, task: str) -> str:
        return resolve_task(task).name

    def instruction(self, task: str) -> str:
        return resolve_task(task).instruction

    def make_env(self, task: str, cfg: Any) -> AlohaEnv:
        return AlohaEnv(
            task,
            cameras=cfg.cameras,
            image_size=cfg.image_size,
            max_steps=cfg.max_steps,
            gl_backend=cfg.gl_backend or None,
            perturbation=parse_perturbation(cfg.perturbation),
        )

    def rollout(
        self, env: AlohaEnv, seed: int, action_noise: float, max_steps: int
    ) -> tuple[Episode, dict[str, Any]]:
        return rollout_aloha_expert(env, seed, action_noise=action_noise, max_steps=max_steps)
