"""Closed-loop evaluation in simulation: paired seeds, perturbation conditions, Wilson intervals, videos.

    gazereg eval --checkpoints baseline=runs/a/final gaze=runs/b/final --tasks reach-v3 --episodes 20 \
        --conditions clean dim:0.7 gaussian_noise:0.5

`--env libero --tasks libero_spatial` evaluates in LIBERO instead (run it with the LIBERO venv's Python:
`bash scripts/libero_env.sh gazereg eval ...`). A LIBERO setup seed is a fixed initial state (`s % 50` for
one task; from 10,000 on a sampled placement instead: `gazereg.envs.libero.setup.setup_index`), so the default
seed_start (1000) is initial state 0, where demonstrations start too:
`--preset libero-spatial-25` evaluates LIBERO-Spatial task by task on initial states 25..49 instead. Every checkpoint ("arm") is rolled out on the same list of setup seeds per task and under every condition
(a perturbation spec, `gazereg.envs.perturbations`), so arms form pairs seed by seed. Evaluation seeds start at
`seed_start` (default 1000, i.e. Meta-World benchmark seed 20's setups), away from the setups demonstrations
are collected on (seeds from 0). One worker process per core; each loads each checkpoint once and steps
`--batch` environments of one checkpoint, task and condition in lockstep, one batched policy call per step.
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
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from gazereg.attention import AttentionProbe
from gazereg.attention.probe import ProbeSpec
from gazereg.envs.base import env_class, simulator
from gazereg.envs.cache import WORKER_ENVS, EnvCache
from gazereg.envs.interface import Env
from gazereg.envs.perturbations import parse_perturbation
from gazereg.evaluation.config import (
    DEFAULT_PRESET,
    EvalConfig,
    check_tasks,
    parse_checkpoints,
    presets,
)
from gazereg.evaluation.summary import format_table, summarize
from gazereg.patches import grid_to_image
from gazereg.policies import load_policy
from gazereg.runtime.config import parse, to_dict
from gazereg.runtime.io import atomic_write_json, sweep_stale_temps
from gazereg.runtime.pool import ResumeLog, Worker, WorkerPool, fingerprint_files
from gazereg.runtime.progress import Progress
from gazereg.viz.overlay import overlay, write_gif

log = logging.getLogger(__name__)


EnvKey = tuple[str, tuple[str, ...], tuple[int, int], int]
"""(task, cameras, image size (H, W), slot): what one evaluation environment is made for; slot k is the
environment of the k-th episode of a lockstep batch"""


@dataclass(frozen=True)
class Job:
    arm: str
    checkpoint: str
    task: str
    condition: str
    seed: int
    video: str | None  # GIF path, or None

    @property
    def batch_key(self) -> tuple[str, str, str]:
        """(checkpoint, task, condition): jobs may be rolled out together only when these agree."""
        return self.checkpoint, self.task, self.condition


@dataclass
class Episode:
    """One rollout's progress: its outcome so far and the simulator's object (or hand) to target distances."""

    job: Job
    distances: list[float]
    success: bool = False
    length: int = 0
    done: bool = False
    video: str | None = None
    max_reward: float | None = None
    """the highest reward the simulator reported (a staged task reward: Gym-Aloha's 0..4); None when its info
    has no `reward`"""

    def record(self, step: int, info: dict[str, Any], ended: bool) -> None:
        self.success = self.success or bool(info["success"])
        if "obj_to_target" in info:
            self.distances.append(float(info["obj_to_target"]))
        if "reward" in info:
            r = float(info["reward"])
            self.max_reward = r if self.max_reward is None else max(r, self.max_reward)
        self.length, self.done = step, ended

    def result(self) -> dict[str, Any]:
        j = self.job
        out = {"arm": j.arm, "task": j.task, "condition": j.condition, "seed": j.seed}
        out.update(success=self.success, length=self.length)
        if self.distances:  # the simulator's progress measure (Meta-World: object, or hand, to target; m)
            out["min_distance"] = min(self.distances)
            out["final_distance"] = self.distances[-1]
        if self.max_reward is not None:  # how far a failed episode got (Gym-Aloha: 1 touch ... 4 success)
            out["max_reward"] = self.max_reward
        if self.video:
            out["video"] = self.video
        return out


@dataclass
class Film:
    """A filmed rollout's frames (camera image beside the attention over it) and its latest attention."""

    spec: ProbeSpec
    camera: str
    frames: list[np.ndarray] = field(default_factory=list)
    attention: np.ndarray | None = None


class RolloutWorker:
    """Per-process state: loaded policies and environments, reused across jobs (`batch` environments per task,
    kept for two tasks at a time: jobs alternate between tasks).

    A job's record: arm, task, condition, seed, success, length (steps) and, where the simulator measures it,
    min_distance and final_distance (metres, object or hand to target) and max_reward (the highest staged
    reward of the episode), video (the GIF's path) if filmed."""

    def __init__(self, max_steps: int, gl_backend: str | None, env: str = "metaworld", batch: int = 1):
        torch.set_num_threads(1)
        simulator(env)  # UnknownSimulator (a UsageError) names the registered ones
        self.max_steps, self.gl_backend, self.env_kind = max_steps, gl_backend, env
        self.policies: dict[str, Any] = {}
        self.envs: EnvCache[EnvKey] = EnvCache(self._make_env, size=max(WORKER_ENVS, 2 * batch))

    def policy(self, checkpoint: str) -> Any:
        if checkpoint not in self.policies:
            self.policies[checkpoint] = load_policy(checkpoint)
        return self.policies[checkpoint]

    def _make_env(self, key: EnvKey) -> Env:
        task, cameras, size, _slot = key
        return env_class(self.env_kind)(
            task, cameras=cameras, image_size=size, max_steps=self.max_steps, gl_backend=self.gl_backend
        )

    def env(self, task: str, cameras: tuple[str, ...], size: tuple[int, int], slot: int = 0) -> Env:
        """The task's environment `slot` (one for every condition: each reset applies its job's perturbation)."""
        return self.envs.get((task, cameras, size, slot))

    def run(self, jobs: Sequence[Job]) -> list[dict[str, Any]]:
        """Roll out `jobs` (one checkpoint, task and condition; see `group_jobs`) in lockstep, one environment
        each and one batched `select_action` per step; their records in order. A filmed job runs alone."""
        first = jobs[0]
        if any(j.batch_key != first.batch_key for j in jobs):
            raise ValueError("jobs rolled out together must share their checkpoint, task and condition")
        if len(jobs) > 1 and any(j.video for j in jobs):
            raise ValueError("a filmed episode is rolled out alone")
        policy = self.policy(first.checkpoint)
        cfg = policy.config
        cams = tuple(cfg.cameras)
        size = tuple(cfg.camera_hw[0]) if cfg.camera_hw else tuple(cfg.image_hw)
        envs = [self.env(first.task, cams, size, slot) for slot in range(len(jobs))]
        perturbation = parse_perturbation("" if first.condition == "clean" else first.condition)
        obs, episodes = [], []
        for env, job in zip(envs, jobs, strict=True):
            o, info = env.reset(seed=job.seed, options={"perturbation": perturbation})
            obs.append(o)
            episodes.append(Episode(job, [info["obj_to_target"]] if "obj_to_target" in info else []))
        policy.reset()
        film = Film(policy.gaze_probe_spec(cams[0]), cams[0]) if first.video else None
        for step in range(1, self.max_steps + 1):
            actions = self._act(policy, obs, film)
            for i, (env, ep) in enumerate(zip(envs, episodes, strict=True)):
                if ep.done:  # finished episodes stay in the batch (a fixed batch), their actions unused
                    continue
                obs[i], _, terminated, truncated, info = env.step(actions[i])
                ep.record(step, info, terminated or truncated)
            if all(ep.done for ep in episodes):
                break
        if film is not None and film.frames:
            write_gif(first.video, film.frames)
            episodes[0].video = first.video
        return [ep.result() for ep in episodes]

    def _act(self, policy: Any, obs: list[dict[str, Any]], film: Film | None) -> np.ndarray:
        """(n, A) actions for the n observations; a filmed episode's frame (attention overlaid) is kept."""
        if film is None:
            batch = {
                "state": np.stack([o["state"] for o in obs]),
                "images": {c: np.stack([o["images"][c] for o in obs]) for c in obs[0]["images"]},
            }
            return policy.select_action(batch, [o["instruction"] for o in obs])
        return self._act_filmed(policy, film, obs[0])[None]

    def _act_filmed(self, policy: Any, film: Film, obs: dict[str, Any]) -> np.ndarray:
        """The policy's action (A,) with its attention captured: updates `film.attention` (n_patches,) when the
        probe saw a layer and appends the frame with the latest attention overlaid to `film.frames`."""
        with AttentionProbe(policy, film.spec, adapter="tap") as probe:
            action = policy.select_action(obs, obs["instruction"])
        if probe.layers:
            film.attention = probe.distribution()[0].numpy()
        film.frames.append(self._frame(policy, film.camera, obs["images"][film.camera], film.attention))
        return action

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


def group_jobs(jobs: Sequence[Job], batch: int) -> list[tuple[int, ...]]:
    """Indices of `jobs` rolled out together: runs of consecutive jobs of one checkpoint, task and condition,
    at most `batch` each; a filmed job alone. Depends on the job list only, never on what a resume skips, so a
    rollout always runs in the same batch (batched matmuls round differently from single ones)."""
    groups: list[list[int]] = []
    for i, job in enumerate(jobs):
        last = jobs[groups[-1][-1]] if groups else None
        joins = (
            last is not None
            and not job.video
            and not last.video
            and len(groups[-1]) < batch
            and last.batch_key == job.batch_key
        )
        if joins:
            groups[-1].append(i)
        else:
            groups.append([i])
    return [tuple(g) for g in groups]


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
    make_worker: Callable[[], Worker[Sequence[Job], list[dict[str, Any]]]] | None = None,
    label: str = "eval",
) -> list[dict[str, Any]]:
    """Run rollouts in `cfg.workers` processes (one when there is at most one batch to run),
    `cfg.lockstep()` environments in lockstep per worker (`group_jobs`).

    With `log_path`, every finished rollout is appended to that resume log and a batch whose rollouts are all in
    it is not run again (one with any missing runs whole), so a killed evaluation resumes where it stopped.
    Records come back in job order.
    `make_worker`: builds a process's worker (default: a `RolloutWorker` with cfg's max_steps, gl_backend, env
    and lockstep()). `progress`: rollouts done of all, with the rate and ETA, on stderr as `label`
    (`gazereg.runtime.progress`)."""
    prints = {c: fingerprint_files(c) for c in {j.checkpoint for j in jobs}}
    keys = [job_key(j, cfg.max_steps, cfg.env, prints) for j in jobs]
    episodes = ResumeLog(log_path) if log_path is not None else None
    done = episodes.read() if episodes is not None else {}
    todo = [g for g in group_jobs(jobs, cfg.lockstep()) if any(keys[i] not in done for i in g)]
    n_todo = sum(len(g) for g in todo)
    if n_todo < len(jobs):
        log.info("resuming evaluation: %d of %d rollouts already logged", len(jobs) - n_todo, len(jobs))
    results: dict[int, dict[str, Any]] = {i: done[k] for i, k in enumerate(keys) if k in done}
    make_worker = make_worker or functools.partial(
        RolloutWorker, cfg.max_steps, cfg.gl_backend, cfg.env, cfg.lockstep()
    )
    workers = 1 if len(todo) <= 1 else min(cfg.workers, len(todo))
    with (
        WorkerPool(make_worker, workers) as pool,
        Progress(label, len(jobs), "episodes", done=len(jobs) - n_todo, enabled=progress) as bar,
    ):
        for g in todo:
            pool.submit([jobs[i] for i in g], tag=g)
        for g, records in pool.results():
            for i, record in zip(g, records, strict=True):
                results[i] = record
                if episodes is not None:
                    episodes.append(keys[i], record)
            bar.update(len(g))
    return [results[i] for i in range(len(jobs))]


def preflight(cfg: EvalConfig, flag_prefix: str = "") -> dict[str, Path]:
    """Everything `evaluate` can check before its first rollout: the tasks against the simulator's registry
    (`check_tasks`), then the checkpoints (`parse_checkpoints`); returns {name: checkpoint folder}. A bad one
    is a UsageError naming its option (after `flag_prefix`, e.g. "eval.")."""
    check_tasks(cfg.env, cfg.tasks, f"--{flag_prefix}tasks")
    return parse_checkpoints(cfg.checkpoints, f"--{flag_prefix}checkpoints")


def evaluate(cfg: EvalConfig, progress: bool = True) -> dict[str, Any]:
    """Evaluate every checkpoint; writes and returns the evaluation record (eval_info.json). Checkpoints that
    are not saved policies and tasks the simulator does not know are refused first (`preflight`), then the
    temporaries that killed writers left in `cfg.out` are removed."""
    arms = preflight(cfg)
    jobs = make_jobs(cfg, arms)
    out = Path(cfg.out)
    sweep_stale_temps(out)
    records = run_jobs(jobs, cfg, progress, log_path=out / "episodes.jsonl", label=f"eval {out}")
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
        presets(),
        sys.argv[1:] if argv is None else argv,
        prog="gazereg eval",
        description=__doc__ or "",
        default=DEFAULT_PRESET,
    )
    info = evaluate(cfg)
    print(format_table(info["summary"]))
    print(f"wrote {Path(cfg.out) / 'eval_info.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
