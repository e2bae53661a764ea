"""Closed-loop evaluation in simulation: paired seeds, perturbation conditions, Wilson intervals, videos.

    gazereg eval --checkpoints baseline=runs/a/final gaze=runs/b/final --tasks reach-v3 --episodes 20 \
        --conditions clean dim:0.7 gaussian_noise:0.5

`--env libero --tasks libero_spatial` evaluates in LIBERO instead (run it with the LIBERO venv's Python:
`bash scripts/libero_env.sh gazereg eval ...`). A LIBERO setup seed is a fixed initial state (`s % 50` for
one task), so the default seed_start (1000) is initial state 0, where demonstrations start too:
`--preset libero` evaluates LIBERO-Spatial task by task on initial states 25..49 instead. Every checkpoint ("arm") is rolled out on the same list of setup seeds per task and under every condition
(a perturbation spec, `gazereg.envs.perturbations`), so arms form pairs seed by seed. Evaluation seeds start at
`seed_start` (default 1000, i.e. Meta-World benchmark seed 20's setups), away from the setups demonstrations
are collected on (seeds from 0). One worker process per core; each loads each checkpoint once.
Writes `eval_info.json` (config, seeds actually used, every episode's outcome -- success, length and, where
the simulator measures it, the closest and final distance of the object (or hand) to its target in metres --
and summaries) and GIF videos
of the first `videos` episodes per arm, task and condition with the policy's attention overlaid. Every
finished rollout is also appended to `episodes.jsonl`; a rerun into the same `--out` reuses the rollouts
logged there for the same checkpoint files, task, condition and seed, so a killed evaluation resumes.
Settings and presets: `gazereg.evaluation.config`; summaries: `gazereg.evaluation.summary`; the worker
processes, the episode log and the checkpoint fingerprints: `gazereg.runtime.pool`.
"""

from __future__ import annotations

import functools
import json
import logging
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from gazereg.attention import AttentionProbe
from gazereg.envs.base import Env, env_class, simulator
from gazereg.envs.cache import EnvCache
from gazereg.envs.perturbations import parse_perturbation
from gazereg.evaluation.config import EvalConfig, parse_checkpoints, presets
from gazereg.evaluation.summary import format_table, summarize
from gazereg.patches import grid_to_image
from gazereg.policies import load_policy
from gazereg.runtime.config import parse, to_dict
from gazereg.runtime.io import atomic_write_json, sweep_stale_temps
from gazereg.runtime.pool import ResumeLog, Worker, WorkerPool, fingerprint_files
from gazereg.viz.overlay import overlay, write_gif

log = logging.getLogger(__name__)


EnvKey = tuple[str, tuple[str, ...], tuple[int, int]]
"""(task, cameras, image size (H, W)): what one evaluation environment is made for"""


@dataclass(frozen=True)
class Job:
    arm: str
    checkpoint: str
    task: str
    condition: str
    seed: int
    video: str | None  # GIF path, or None


class RolloutWorker:
    """Per-process state: loaded policies and environments, reused across jobs.

    A job's record: arm, task, condition, seed, success, length (steps) and, where the simulator measures it,
    min_distance and final_distance (metres, object or hand to target), video (the GIF's path) if filmed."""

    def __init__(self, max_steps: int, gl_backend: str | None, env: str = "metaworld"):
        torch.set_num_threads(1)
        simulator(env)  # UnknownSimulator (a UsageError) names the registered ones
        self.max_steps, self.gl_backend, self.env_kind = max_steps, gl_backend, env
        self.policies: dict[str, Any] = {}
        self.envs: EnvCache[EnvKey] = EnvCache(self._make_env)

    def policy(self, checkpoint: str) -> Any:
        if checkpoint not in self.policies:
            self.policies[checkpoint] = load_policy(checkpoint)
        return self.policies[checkpoint]

    def _make_env(self, key: EnvKey) -> Env:
        task, cameras, size = key
        return env_class(self.env_kind)(
            task, cameras=cameras, image_size=size, max_steps=self.max_steps, gl_backend=self.gl_backend
        )

    def env(self, task: str, cameras: tuple[str, ...], size: tuple[int, int]) -> Env:
        """The task's environment (one for every condition: each reset applies its job's perturbation)."""
        return self.envs.get((task, cameras, size))

    def run(self, job: Job) -> dict[str, Any]:
        policy = self.policy(job.checkpoint)
        cfg = policy.config
        cams = tuple(cfg.cameras)
        size = tuple(cfg.camera_hw[0]) if cfg.camera_hw else tuple(cfg.image_hw)
        env = self.env(job.task, cams, size)
        perturbation = parse_perturbation("" if job.condition == "clean" else job.condition)
        obs, info = env.reset(seed=job.seed, options={"perturbation": perturbation})
        policy.reset()
        frames: list[np.ndarray] = []
        probe_spec = policy.gaze_probe_spec(cams[0]) if job.video else None
        attn = None
        success, steps = False, 0
        distances = [info["obj_to_target"]] if "obj_to_target" in info else []
        for steps in range(1, self.max_steps + 1):  # noqa: B007 (steps is the episode length)
            if probe_spec is not None:
                action, attn = self._act_filmed(policy, probe_spec, obs, cams[0], attn, frames)
            else:
                action = policy.select_action(obs, obs["instruction"])
            obs, _, terminated, truncated, info = env.step(action)
            success = success or bool(info["success"])
            if "obj_to_target" in info:
                distances.append(float(info["obj_to_target"]))
            if terminated or truncated:
                break
        out = {
            "arm": job.arm,
            "task": job.task,
            "condition": job.condition,
            "seed": job.seed,
            "success": success,
            "length": steps,
        }
        if distances:  # the simulator's own progress measure (Meta-World: object, or hand, to target; metres)
            out["min_distance"] = min(distances)
            out["final_distance"] = distances[-1]
        if job.video and frames:
            write_gif(job.video, frames)
            out["video"] = job.video
        return out

    def _act_filmed(
        self,
        policy: Any,
        spec: Any,
        obs: dict[str, Any],
        camera: str,
        attn: np.ndarray | None,
        frames: list[np.ndarray],
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The policy's action with its attention captured; appends the frame (with the latest attention
        (n_patches,) overlaid) to `frames`. Returns (action, latest attention or None)."""
        with AttentionProbe(policy, spec, adapter="tap") as probe:
            action = policy.select_action(obs, obs["instruction"])
        if probe.layers:
            attn = probe.distribution()[0].numpy()
        frames.append(self._frame(policy, camera, obs["images"][camera], attn))
        return action, attn

    @staticmethod
    def _frame(policy: Any, camera: str, image: np.ndarray, attn: np.ndarray | None) -> np.ndarray:
        """uint8 (H, W, 3) camera image -> (H, 2W, 3): the image and the attention over it (or the image alone)."""
        if attn is None:
            return np.asarray(image)
        heat = grid_to_image(attn, policy.geometry(camera), image.shape[:2]).numpy()
        return np.concatenate([np.asarray(image), overlay(np.asarray(image), heat)], axis=1)

    def close(self) -> None:
        self.envs.close()


def make_jobs(cfg: EvalConfig, arms: dict[str, Path]) -> list[Job]:
    """Every rollout: each arm on each task's setups under each condition (`EvalConfig.seeds`)."""
    jobs = []
    for arm, ckpt in arms.items():
        for task in cfg.tasks:
            for condition in cfg.conditions:
                for i, seed in enumerate(cfg.seeds(condition)):
                    video = None
                    if i < cfg.videos:
                        tag = condition.replace(":", "").replace("+", "_")
                        name = f"{arm}__{task}__{tag}__seed{seed}".replace("/", "-")
                        video = str(Path(cfg.out) / "videos" / f"{name}.gif")
                    jobs.append(Job(arm, str(ckpt), task, condition, seed, video))
    return jobs


def job_key(job: Job, max_steps: int, env: str, prints: dict[str, str]) -> str:
    """What makes two rollouts the same: a logged record is reused only for an identical job.
    `prints`: each checkpoint's `fingerprint_files`."""
    return json.dumps(
        [job.arm, job.checkpoint, prints[job.checkpoint], job.task, job.condition, job.seed, max_steps, env]
    )


def run_jobs(
    jobs: list[Job],
    cfg: EvalConfig,
    progress: bool = True,
    log_path: Path | None = None,
    make_worker: Callable[[], Worker[Job, dict[str, Any]]] | None = None,
) -> list[dict[str, Any]]:
    """Run rollouts in `cfg.workers` processes (one when there is at most one rollout to run).

    With `log_path`, every finished rollout is appended to that resume log and rollouts already in it are not
    run again, so a killed evaluation resumes where it stopped. Records come back in job order.
    `make_worker`: builds a process's worker (default: a `RolloutWorker` with cfg's max_steps, gl_backend, env)."""
    prints = {c: fingerprint_files(c) for c in {j.checkpoint for j in jobs}}
    keys = [job_key(j, cfg.max_steps, cfg.env, prints) for j in jobs]
    episodes = ResumeLog(log_path) if log_path is not None else None
    done = episodes.read() if episodes is not None else {}
    todo = [i for i, k in enumerate(keys) if k not in done]
    if len(todo) < len(jobs):
        log.info("resuming evaluation: %d of %d rollouts already logged", len(jobs) - len(todo), len(jobs))
    results: dict[int, dict[str, Any]] = {i: done[k] for i, k in enumerate(keys) if k in done}
    make_worker = make_worker or functools.partial(RolloutWorker, cfg.max_steps, cfg.gl_backend, cfg.env)
    workers = 1 if len(todo) <= 1 else min(cfg.workers, len(todo))
    with (
        WorkerPool(make_worker, workers) as pool,
        tqdm(total=len(todo), desc="eval", disable=not progress) as bar,
    ):
        for i in todo:
            pool.submit(jobs[i], tag=i)
        for i, record in pool.results():
            results[i] = record
            if episodes is not None:
                episodes.append(keys[i], record)
            bar.update()
    return [results[i] for i in range(len(jobs))]


def evaluate(cfg: EvalConfig, progress: bool = True) -> dict[str, Any]:
    """Evaluate every checkpoint; writes and returns the evaluation record (eval_info.json). Checkpoints that
    are not saved policies are refused first (`parse_checkpoints`: UsageError naming --checkpoints), then the
    temporaries that killed writers left in `cfg.out` are removed."""
    arms = parse_checkpoints(cfg.checkpoints)
    jobs = make_jobs(cfg, arms)
    out = Path(cfg.out)
    sweep_stale_temps(out)
    records = run_jobs(jobs, cfg, progress, log_path=out / "episodes.jsonl")
    info = {
        "config": to_dict(cfg),
        "checkpoints": {k: str(v) for k, v in arms.items()},
        "seeds": {t: list(range(cfg.seed_start, cfg.seed_start + cfg.episodes)) for t in cfg.tasks},
        "condition_seeds": {c: list(cfg.seeds(c)) for c in cfg.conditions},
        "episodes": records,
        "summary": summarize(records),
    }
    atomic_write_json(out / "eval_info.json", info)
    return info


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    cfg = parse(
        presets(), sys.argv[1:] if argv is None else argv, prog="gazereg eval", description=__doc__ or ""
    )
    info = evaluate(cfg)
    print(format_table(info["summary"]))
    print(f"wrote {Path(cfg.out) / 'eval_info.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
