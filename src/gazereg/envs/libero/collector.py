"""LIBERO demonstrations: the suite's scripted expert rolled out into episodes (`gazereg collect --env libero`).

    ep, summary = rollout_libero_expert(env, seed=3)    # on setup 3 of a LiberoEnv (one task or a suite)
    make_expert("libero_object", noise=0.1)             # the suite's expert (EXPERTS)

Experts: LIBERO-Spatial `SpatialExpert` (a bowl onto the plate), LIBERO-Object `ObjectExpert` (an item into the
basket), LIBERO-Goal `GoalExpert` (a plan per goal predicate: open a drawer, turn a knob, push, place;
`gazereg.envs.libero.expert_goal`), LIBERO-10 `LongExpert` (a step per conjunct of the goal: open, turn on, place
one or two objects, close a drawer or the microwave; `gazereg.envs.libero.expert_10`).

The episode's task is LIBERO's task name (as `gazereg import hdf5` names LIBERO's demonstrations); its meta:
seed, setup (suite, task index, initial state), success, fps, env, env_name, steps, expert, the expert's grasp,
action_noise, the task's roles, the expert's gaze targets when it names them (`gaze_targets`: GoalExpert's,
e.g. ["handle"] for a drawer; LongExpert's, e.g. ["knob", "obj", "goal", "obj2", "goal2"] for LIBERO-10's two
moka pots; their `<name>_pos`, `<name>_uv.<camera>` and `contact.<name>` extras come with them, for the
visuomotor gaze source), camera geometry (MuJoCo's, with `mirror_u`: the stored images are its
view mirrored left-right), state and action layouts, package versions. Importing this module does not import
LIBERO.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from gazereg.data.store import Episode
from gazereg.envs.libero.env import ACTION_LAYOUT, STATE_LAYOUT, LiberoEnv
from gazereg.envs.libero.expert import PickPlaceExpert, SpatialExpert
from gazereg.envs.libero.expert_10 import LongExpert
from gazereg.envs.libero.expert_goal import GoalExpert
from gazereg.envs.libero.expert_object import ObjectExpert
from gazereg.envs.libero.setup import import_libero, libero_available, resolve_task, suite_benchmark
from gazereg.envs.perturbations import parse_perturbation
from gazereg.envs.recording import noise_seed, record_rollout, summary_of, versions

# The scripted expert of each suite that has one.
EXPERTS: dict[str, type[PickPlaceExpert]] = {
    "libero_spatial": SpatialExpert,
    "libero_object": ObjectExpert,
    "libero_goal": GoalExpert,
    "libero_10": LongExpert,
}


def make_expert(suite: str, noise: float = 0.0) -> PickPlaceExpert:
    """A new expert for the tasks of `suite` with action noise `noise`; ValueError for a suite without one."""
    if suite not in EXPERTS:
        raise ValueError(f"no scripted LIBERO expert for {suite!r}; experts cover {', '.join(EXPERTS)}")
    return EXPERTS[suite](noise=noise)


def rollout_libero_expert(
    env: LiberoEnv,
    seed: int,
    action_noise: float = 0.0,
    max_steps: int | None = None,
    expert: PickPlaceExpert | None = None,
) -> tuple[Episode, dict[str, Any]]:
    """Roll the suite's expert (`make_expert`) out on setup `seed` of `env`.

    Returns the Episode (also when it failed: meta["success"] says) and the summary `gazereg collect` logs."""
    expert = expert or make_expert(env.suite, action_noise)
    started = False
    # The expert's own gaze parts (GoalExpert: a drawer's handle, a knob; LongExpert: obj2, goal2 too), per
    # frame: position (3,), touched, camera -> uv (2,).
    parts: dict[str, list[tuple[np.ndarray, bool, dict[str, np.ndarray]]]] = {}

    def act(obs: dict[str, Any], info: dict[str, Any]) -> np.ndarray:
        nonlocal started
        if not started:  # the env has just been reset by record_rollout
            expert.reset(env, noise_seed(env.task, seed))
            started = True
        if hasattr(expert, "gaze_points"):  # the state of frame t, before its action
            for name, (pos, touched) in expert.gaze_points(env).items():
                uv = {c: env.project(pos, c) for c in env.cameras}  # now: the wrist camera moves
                parts.setdefault(name, []).append((pos, touched, uv))
        return expert(env)

    rec = record_rollout(env, act, seed, max_steps or env.max_steps)
    for name, seq in parts.items():  # as record_rollout's key points: <name>_pos, <name>_uv.<camera>
        rec.extras[f"{name}_pos"] = np.asarray([p for p, _, _ in seq], dtype=np.float32)
        rec.extras[f"contact.{name}"] = np.asarray([t for _, t, _ in seq], dtype=bool)
        for c in env.cameras:
            rec.extras[f"{name}_uv.{c}"] = np.asarray([uv[c] for _, _, uv in seq], dtype=np.float32)
    t, k = env.setup_of(seed)
    meta = {
        "seed": int(seed),
        "setup": {"benchmark": "libero", "suite": env.suite, "task_index": t, "init_state": k},
        "success": bool(rec.success),
        "fps": float(env.fps),
        "env": "libero",
        "env_name": env.task,
        "steps": rec.length,
        "expert": expert.name,
        "expert_grasp": dict(expert.grasp_choice),
        "action_noise": float(action_noise),
        "roles": {"obj": env.roles.obj, "goal": env.roles.goal, "relation": env.roles.relation},
        **({"gaze_targets": list(expert.gaze_targets)} if hasattr(expert, "gaze_targets") else {}),
        # MuJoCo's geometry of each camera; the stored images are its view mirrored left-right (LIBERO's turn).
        "camera_geometry": {c: {**env.camera_geometry(c).to_dict(), "mirror_u": True} for c in env.cameras},
        "state_layout": list(STATE_LAYOUT),
        "action_layout": list(ACTION_LAYOUT),
        "versions": versions(("hf-libero", "robosuite", "mujoco", "gazereg")),
    }
    return rec.episode(env.task_names[t], env.instruction, meta), summary_of(env.task, seed, rec)


class LiberoCollector:
    """`gazereg collect --env libero`: the tasks of the suites with a scripted expert (EXPERTS), each rolled out
    by its suite's.

    Tasks: a suite (`libero_spatial`, `libero_object`, `libero_goal`, `libero_10`: its 10 tasks),
    `libero_object/3`, `libero_object/<task name>`; canonical form `<suite>/<index>`. Seed s is the task's fixed
    initial state s % 50. Episodes are `default_max_steps` long unless `--max_steps` says otherwise (LIBERO-Spatial's
    evaluation length; the experts finish LIBERO-Object's tasks within it too; LIBERO-Goal's need up to its 300,
    LIBERO-10's up to its 520: docs/benchmarks/)."""

    name = "libero"
    default_cameras = ("agentview_rgb", "eye_in_hand_rgb")  # the names `gazereg import hdf5` gives them
    default_max_steps = 220  # LIBERO-Spatial's evaluation length
    max_steps_limit = 10_000
    suites = tuple(EXPERTS)

    def tasks(self, requested: Sequence[str]) -> tuple[str, ...]:
        """Canonical task specs (suites expanded); ValueError/KeyError for unknown or unsupported ones."""
        ok, why = libero_available()
        if not ok:
            raise ValueError(f"--env libero: {why}")
        import_libero(None)
        out: list[str] = []
        for spec in requested:
            suite, index = resolve_task(spec)
            if suite not in self.suites:
                raise ValueError(
                    f"{spec!r}: the scripted LIBERO experts cover {', '.join(self.suites)} only "
                    "(a bowl onto the plate, an item into the basket, LIBERO-Goal's kitchen, LIBERO-10's long tasks)"
                )
            n = len(suite_benchmark(suite).get_task_names())
            out += [f"{suite}/{i}" for i in (range(n) if index is None else [index])]
        return tuple(out)

    def episode_task(self, task: str) -> str:
        suite, index = resolve_task(task)
        return str(suite_benchmark(suite).get_task_names()[index])

    def instruction(self, task: str) -> str:
        # tasks() imports LIBERO without its prompts and refuses what the experts do not cover
        (one,) = self.tasks([task])
        suite, index = resolve_task(one)
        return str(suite_benchmark(suite).get_task(index).language)  # as LiberoEnv's episodes store it

    def make_env(self, task: str, cfg: Any) -> LiberoEnv:
        return LiberoEnv(
            task,
            cameras=cfg.cameras,
            image_size=cfg.image_size,
            max_steps=cfg.max_steps,
            gl_backend=cfg.gl_backend or None,
            perturbation=parse_perturbation(cfg.perturbation),
        )

    def rollout(
        self, env: LiberoEnv, seed: int, action_noise: float, max_steps: int
    ) -> tuple[Episode, dict[str, Any]]:
        return rollout_libero_expert(env, seed, action_noise=action_noise, max_steps=max_steps)
