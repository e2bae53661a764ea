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
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import sys
from collections import defaultdict
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any, Literal

import numpy as np
from tqdm import tqdm

from gazereg.evaluation.stats import mcnemar_exact, wilson
from gazereg.runtime.config import to_dict
from gazereg.runtime.io import atomic_write_json

log = logging.getLogger(__name__)


# simulator name -> "module:Class" (imported in the worker only when used)
ENVS = {"metaworld": "gazereg.envs.metaworld.env:MetaWorldEnv", "libero": "gazereg.envs.libero.env:LiberoEnv"}


# The full robustness sweep: each lighting perturbation and several sensor-noise levels.
ROBUSTNESS_CONDITIONS = (
    "clean",
    "dim:0.7",
    "bright:0.7",
    "tint:1",
    "light_direction:1",
    "gaussian_noise:0.3",
    "gaussian_noise:0.6",
    "salt_pepper:0.5",
)


@dataclass(frozen=True)
class EvalConfig:
    checkpoints: tuple[str, ...] = ()
    """policies to evaluate: NAME=DIR or DIR (named after the folder)"""
    tasks: tuple[str, ...] = ("reach-v3",)
    episodes: int = 10
    """episodes per task and condition (setup seeds seed_start .. seed_start + episodes - 1)"""
    seed_start: int = 1000
    conditions: tuple[str, ...] = ("clean",)
    """perturbation specs, e.g. clean, dim:0.7, tint:1, gaussian_noise:0.5, salt_pepper:0.5, dim:0.5+gaussian_noise:0.3"""
    max_steps: int = 150
    workers: int = 2
    """worker processes (one per core); 1 runs in this process"""
    videos: int = 1
    """episodes per (arm, task, condition) saved as GIFs with the attention overlay (0: none)"""
    out: Path = Path("runs/eval")
    gl_backend: str | None = None
    """MuJoCo OpenGL backend (egl | osmesa | glfw); None: respect MUJOCO_GL, else egl, else osmesa"""
    env: Literal["metaworld", "libero"] = "metaworld"
    """simulator: metaworld (tasks are Meta-World task names) or libero (tasks are suites such as
    libero_spatial or single tasks such as libero_spatial/3; needs the LIBERO extra: scripts/libero_env.sh)"""


def parse_checkpoints(items: Sequence[str]) -> dict[str, Path]:
    arms: dict[str, Path] = {}
    for item in items:
        name, _, path = item.rpartition("=") if "=" in item else (Path(item).name, "", item)
        if name in arms:
            raise ValueError(f"two checkpoints named {name!r}; name them NAME=DIR")
        if not (Path(path) / "config.json").exists():
            raise FileNotFoundError(
                f"checkpoint {path!r} ({name}) is not a saved policy folder (no config.json)"
            )
        arms[name] = Path(path)
    if not arms:
        raise ValueError("no checkpoints to evaluate: pass --checkpoints NAME=DIR ...")
    return arms


@dataclass(frozen=True)
class Job:
    arm: str
    checkpoint: str
    task: str
    condition: str
    seed: int
    video: str | None  # GIF path, or None


class Worker:
    """Per-process state: loaded policies and environments, reused across jobs."""

    def __init__(self, max_steps: int, gl_backend: str | None, env: str = "metaworld"):
        import torch

        torch.set_num_threads(1)
        if env not in ENVS:
            raise ValueError(f"unknown simulator {env!r}; choose one of {sorted(ENVS)}")
        self.max_steps, self.gl_backend, self.env_kind = max_steps, gl_backend, env
        self.policies: dict[str, Any] = {}
        self.envs: dict[tuple[str, str, tuple[str, ...], tuple[int, int]], Any] = {}

    def policy(self, checkpoint: str) -> Any:
        if checkpoint not in self.policies:
            from gazereg.policies import load_policy

            self.policies[checkpoint] = load_policy(checkpoint)
        return self.policies[checkpoint]

    def env(self, task: str, condition: str, cameras: tuple[str, ...], size: tuple[int, int]) -> Any:
        key = (task, condition, cameras, size)
        if key not in self.envs:
            import importlib

            from gazereg.envs import parse_perturbation

            module, cls = ENVS[self.env_kind].split(":")
            self.envs[key] = getattr(importlib.import_module(module), cls)(
                task,
                cameras=cameras,
                image_size=size,
                max_steps=self.max_steps,
                perturbation=parse_perturbation("" if condition == "clean" else condition),
                gl_backend=self.gl_backend,
            )
        return self.envs[key]

    def run(self, job: Job) -> dict[str, Any]:
        policy = self.policy(job.checkpoint)
        cfg = policy.config
        cams = tuple(cfg.cameras)
        size = tuple(cfg.camera_hw[0]) if cfg.camera_hw else tuple(cfg.image_hw)
        env = self.env(job.task, job.condition, cams, size)
        obs, info = env.reset(seed=job.seed)
        policy.reset()
        frames: list[np.ndarray] = []
        probe_spec = policy.gaze_probe_spec(cams[0]) if job.video else None
        attn = None
        success, steps = False, 0
        distances = [info["obj_to_target"]] if "obj_to_target" in info else []
        for steps in range(1, self.max_steps + 1):  # noqa: B007 (steps is the episode length)
            if probe_spec is not None:
                from gazereg.attention import AttentionProbe

                with AttentionProbe(policy, probe_spec, adapter="tap") as probe:
                    action = policy.select_action(obs, obs["instruction"])
                if probe.layers:
                    attn = probe.distribution()[0].numpy()
                frames.append(self._frame(policy, cams[0], obs["images"][cams[0]], attn))
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
            from gazereg.viz.overlay import write_gif

            write_gif(job.video, frames)
            out["video"] = job.video
        return out

    @staticmethod
    def _frame(policy: Any, camera: str, image: np.ndarray, attn: np.ndarray | None) -> np.ndarray:
        from gazereg.patches import grid_to_image
        from gazereg.viz.overlay import overlay

        if attn is None:
            return np.asarray(image)
        heat = grid_to_image(attn, policy.geometry(camera), image.shape[:2]).numpy()
        return np.concatenate([np.asarray(image), overlay(np.asarray(image), heat)], axis=1)


_WORKER: Worker | None = None


def _init_worker(max_steps: int, gl_backend: str | None, env: str = "metaworld") -> None:
    global _WORKER
    _WORKER = Worker(max_steps, gl_backend, env)


def _run_job(job: Job) -> dict[str, Any]:
    assert _WORKER is not None, "worker not initialised"
    return _WORKER.run(job)


def make_jobs(cfg: EvalConfig, arms: dict[str, Path]) -> list[Job]:
    jobs = []
    for arm, ckpt in arms.items():
        for task in cfg.tasks:
            for condition in cfg.conditions:
                for i in range(cfg.episodes):
                    video = None
                    if i < cfg.videos:
                        tag = condition.replace(":", "").replace("+", "_")
                        name = f"{arm}__{task}__{tag}__seed{cfg.seed_start + i}".replace("/", "-")
                        video = str(Path(cfg.out) / "videos" / f"{name}.gif")
                    jobs.append(Job(arm, str(ckpt), task, condition, cfg.seed_start + i, video))
    return jobs


def fingerprint(checkpoint: str) -> str:
    """Names, sizes and modification times of a checkpoint folder's files: changes when it is rewritten."""
    d = Path(checkpoint)
    stats = [(f.name, f.stat().st_size, f.stat().st_mtime_ns) for f in sorted(d.iterdir()) if f.is_file()]
    return hashlib.sha256(json.dumps(stats).encode()).hexdigest()[:16]


def job_key(job: Job, max_steps: int, env: str, prints: dict[str, str]) -> str:
    """What makes two rollouts the same: a logged record is reused only for an identical job.
    `prints`: each checkpoint's `fingerprint`."""
    return json.dumps(
        [job.arm, job.checkpoint, prints[job.checkpoint], job.task, job.condition, job.seed, max_steps, env]
    )


def read_log(path: Path) -> dict[str, dict[str, Any]]:
    """Finished rollouts from an episode log (JSON lines); a line cut short by a kill is ignored."""
    done: dict[str, dict[str, Any]] = {}
    if not path.exists():
        return done
    for line in path.read_text().splitlines():
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            log.warning("episode log %s: ignoring an unfinished line", path)
            continue
        done[entry["key"]] = entry["record"]
    return done


def run_jobs(
    jobs: list[Job],
    workers: int,
    max_steps: int,
    gl_backend: str | None,
    progress: bool = True,
    env: str = "metaworld",
    log_path: Path | None = None,
) -> list[dict[str, Any]]:
    """Run rollouts in `workers` processes (spawned: MuJoCo and torch threads are not fork-safe).

    With `log_path`, every finished rollout is appended to that JSON-lines log and rollouts already in it
    are not run again, so a killed evaluation resumes where it stopped. Records come back in job order."""
    prints = {c: fingerprint(c) for c in {j.checkpoint for j in jobs}}
    keys = [job_key(j, max_steps, env, prints) for j in jobs]
    done = read_log(log_path) if log_path is not None else {}
    todo = [i for i, k in enumerate(keys) if k not in done]
    if len(todo) < len(jobs):
        log.info("resuming evaluation: %d of %d rollouts already logged", len(jobs) - len(todo), len(jobs))
    results: dict[int, dict[str, Any]] = {i: done[k] for i, k in enumerate(keys) if k in done}
    sink = None
    if log_path is not None:
        log_path.parent.mkdir(parents=True, exist_ok=True)
        sink = log_path.open("a")

    def record(i: int, rec: dict[str, Any]) -> None:
        results[i] = rec
        if sink is not None:
            sink.write(json.dumps({"key": keys[i], "record": rec}) + "\n")
            sink.flush()

    try:
        bar = tqdm(total=len(todo), desc="eval", disable=not progress)
        if workers <= 1 or len(todo) <= 1:
            _init_worker(max_steps, gl_backend, env)
            for i in todo:
                record(i, _run_job(jobs[i]))
                bar.update()
        else:
            with ProcessPoolExecutor(
                min(workers, len(todo)),
                mp_context=get_context("spawn"),
                initializer=_init_worker,
                initargs=(max_steps, gl_backend, env),
            ) as ex:
                futures = {ex.submit(_run_job, jobs[i]): i for i in todo}
                for fut in as_completed(futures):
                    record(futures[fut], fut.result())
                    bar.update()
        bar.close()
    finally:
        if sink is not None:
            sink.close()
    return [results[i] for i in range(len(jobs))]


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Per arm, condition and task: successes, n, rate, Wilson 95% interval, mean length; pooled over tasks;
    each condition's drop from clean; paired exact tests between arms on the shared seeds."""
    by: dict[tuple[str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in records:
        by[(r["arm"], r["condition"], r["task"])].append(r)

    def cell(rs: list[dict[str, Any]]) -> dict[str, Any]:
        k, n = sum(r["success"] for r in rs), len(rs)
        lo, hi = wilson(k, n)
        out = {
            "successes": k,
            "n": n,
            "rate": k / n if n else float("nan"),
            "ci95": [lo, hi],
            "mean_length": float(np.mean([r["length"] for r in rs])) if rs else float("nan"),
        }
        dist = [r["min_distance"] for r in rs if "min_distance" in r]
        if dist:
            out["mean_min_distance"] = float(np.mean(dist))
        return out

    arms = sorted({r["arm"] for r in records})
    conditions = list(dict.fromkeys(r["condition"] for r in records))
    tasks = list(dict.fromkeys(r["task"] for r in records))
    out: dict[str, Any] = {"arms": {}, "paired": {}}
    for arm in arms:
        out["arms"][arm] = {}
        for cond in conditions:
            rs = [r for t in tasks for r in by[(arm, cond, t)]]
            entry = {"pooled": cell(rs), "tasks": {t: cell(by[(arm, cond, t)]) for t in tasks}}
            out["arms"][arm][cond] = entry
        if "clean" in out["arms"][arm]:
            clean = out["arms"][arm]["clean"]["pooled"]["rate"]
            for cond in conditions:
                out["arms"][arm][cond]["drop_from_clean"] = clean - out["arms"][arm][cond]["pooled"]["rate"]

    def outcomes(arm: str, cond: str) -> list[bool]:
        rs = sorted((r for t in tasks for r in by[(arm, cond, t)]), key=lambda r: (r["task"], r["seed"]))
        return [bool(r["success"]) for r in rs]

    for i, a in enumerate(arms):
        for b in arms[i + 1 :]:
            for cond in conditions:
                out["paired"][f"{a} vs {b} | {cond}"] = mcnemar_exact(outcomes(a, cond), outcomes(b, cond))
    return out


def evaluate(cfg: EvalConfig, progress: bool = True) -> dict[str, Any]:
    """Evaluate every checkpoint; writes and returns the evaluation record (eval_info.json)."""
    arms = parse_checkpoints(cfg.checkpoints)
    jobs = make_jobs(cfg, arms)
    out = Path(cfg.out)
    records = run_jobs(
        jobs, cfg.workers, cfg.max_steps, cfg.gl_backend, progress, cfg.env, log_path=out / "episodes.jsonl"
    )
    info = {
        "config": to_dict(cfg),
        "checkpoints": {k: str(v) for k, v in arms.items()},
        "seeds": {t: list(range(cfg.seed_start, cfg.seed_start + cfg.episodes)) for t in cfg.tasks},
        "episodes": records,
        "summary": summarize(records),
    }
    atomic_write_json(out / "eval_info.json", info)
    return info


def format_table(summary: dict[str, Any]) -> str:
    """A markdown table: one row per arm, one column per condition (pooled success, 95% interval)."""
    arms = list(summary["arms"])
    conditions = list(next(iter(summary["arms"].values())))
    lines = ["| arm | " + " | ".join(conditions) + " |", "|---|" + "---|" * len(conditions)]
    for arm in arms:
        cells = []
        for c in conditions:
            p = summary["arms"][arm][c]["pooled"]
            cells.append(
                f"{p['successes']}/{p['n']} = {p['rate']:.2f} [{p['ci95'][0]:.2f}, {p['ci95'][1]:.2f}]"
            )
        lines.append(f"| {arm} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def presets() -> dict[str, Any]:
    return {
        "default": EvalConfig,
        "smoke": lambda: EvalConfig(
            episodes=2, max_steps=20, workers=1, videos=1, conditions=("clean", "dim:0.7")
        ),
        "quick": lambda: EvalConfig(episodes=10, conditions=("clean", "dim:0.7", "gaussian_noise:0.5")),
        # LIBERO-Spatial task by task on initial states 25..49, leaving 0..24 to `gazereg collect --env libero`.
        "libero": lambda: EvalConfig(
            env="libero",
            tasks=tuple(f"libero_spatial/{k}" for k in range(10)),
            episodes=25,
            seed_start=25,
            max_steps=220,
            workers=os.cpu_count() or 2,
        ),
        "paper": lambda: EvalConfig(
            episodes=50,
            max_steps=200,
            workers=os.cpu_count() or 2,
            conditions=ROBUSTNESS_CONDITIONS,
        ),
    }


def main(argv: list[str] | None = None) -> int:
    from gazereg.runtime.config import parse

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
