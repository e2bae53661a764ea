"""`gazereg collect`: roll out scripted experts (Meta-World's, or gazereg's LIBERO-Spatial expert) into a store.

    gazereg collect --preset demos-2x2
    gazereg collect --tasks reach-v3,pick-place-v3 --episodes 5 --out runs/demos
    gazereg collect --tasks reach-v3 pick-place-v3 --episodes 5 --cameras corner2 topview --image-size 128
    bash scripts/libero_env.sh gazereg collect --env libero --tasks libero_spatial/0 --episodes 5 --out runs/lib

`--env libero` (in the LIBERO venv, scripts/libero_env.sh) takes LIBERO tasks (`libero_spatial` for all 10
tasks of the suite, `libero_spatial/3`, `libero_spatial/<task name>`) and rolls out
`gazereg.envs.libero.expert.SpatialExpert` on their fixed initial states (seed s = initial state s % 50 below 10,000); its
episodes carry the same extras, cameras named as `gazereg import hdf5` names LIBERO's (agentview_rgb,
eye_in_hand_rgb), LIBERO's 8-d state and 7-d action, and the LIBERO task name as task (see
`gazereg.envs.libero.expert`). Nothing here imports LIBERO unless --env libero. `gazereg eval --env libero` maps
seeds to initial states the same way (its default seed_start 1000 is initial state 0), so evaluate on initial
states the demonstrations did not use: `--seed-start 40` for demos collected on seeds 0-39.

For each task it rolls out the expert on setup seeds seed_base, seed_base + 1, ... (see
`gazereg.envs.metaworld.env` for how a seed fixes the object and goal positions), keeps the episodes that succeed
within `max_steps` and replaces each failure with the next seed, up to `max_failures` extra seeds per task.
Failures are logged and reported, never stored as episodes.

Episode indices are a function of (task, seed): index = slot * 1000 + (seed - seed_base), slot being the
task's position in `tasks`. A rerun with the same tasks and seed base skips the episodes already in the store
and the seeds that already failed with the same settings, so an interrupted collection resumes where it
stopped. The store refuses to mix settings: an existing episode made from another task, seed or settings at
the same index is an error.

Each episode holds, per frame t (the state before action t): frames per camera, state (hand xyz + gripper
opening), action, and extras
    obj_pos, goal_pos, hand_pos                float32 (T, 3)  world positions (metres); obj2_pos if any
    obj_uv.<cam>, goal_uv.<cam>, hand_uv.<cam>  float32 (T, 2)  normalised (u right, v down) in the image as
                                                                stored; outside [0, 1] when out of view
    contact, grasp                              bool (T,)       gripper touches / both fingers hold an object
    reward, success                             (T,)            the simulator's, after executing action t
and meta: seed, setup (MT1 benchmark seed and index), success, fps, env, env_name, steps, expert,
camera geometry, settings. Workers: one process per core by default, each with its own environments
(`gazereg.runtime.pool`). The per-simulator parts (tasks, environments, the rollout) are collector objects
registered in `gazereg.envs.base`. Settings, presets and their checks: `gazereg.envs.collect_config`.
Every attempt is appended to `<out>/collect/attempts.jsonl` (a `gazereg.runtime.pool.ResumeLog`).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gazereg.data.store import EpisodeStore
from gazereg.envs.base import make_collector
from gazereg.envs.cache import EnvCache
from gazereg.envs.collect_config import (
    DEFAULT_PRESET,
    FINGERPRINT_FIELDS,
    PRESETS,
    CollectConfig,
    CollectError,
    collect_seeds,
    episode_index,
    fingerprint,
    resolve,
)
from gazereg.envs.interface import Collector, Env
from gazereg.runtime.config import parse, save_config
from gazereg.runtime.io import atomic_write_json, sweep_stale_temps
from gazereg.runtime.pool import ResumeLog, WorkerPool, available_cores
from gazereg.runtime.progress import Progress

SINGLE_THREADED = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


class CollectionIncomplete(RuntimeError):
    """A collection that ran but left some task with fewer successful episodes than asked for."""


@dataclass(frozen=True)
class RolloutJob:
    task: str
    seed: int
    index: int  # where the episode goes in the store


class CollectWorker:
    """One process's part of a collection: its environments by task; rolls out a job and stores a success."""

    def __init__(self, cfg: CollectConfig):
        self.cfg = cfg  # resolved
        self.collector: Collector = make_collector(cfg.env)
        self.fingerprint = fingerprint(cfg)
        self.envs: EnvCache[str] = EnvCache(lambda task: self.collector.make_env(task, self.cfg))

    def env(self, task: str) -> Env:
        return self.envs.get(task)

    def run(self, job: RolloutJob) -> dict[str, Any]:
        """Roll out `job`; write the episode to the store if it succeeded. Returns its summary."""
        cfg = self.cfg
        env = self.env(job.task)
        try:
            ep, summary = self.collector.rollout(env, job.seed, cfg.action_noise, cfg.max_steps)
        except Exception as e:  # a simulator error fails this seed, not the collection
            return {
                "task": job.task,
                "seed": job.seed,
                "index": job.index,
                "success": False,
                "steps": 0,
                "seconds": 0.0,
                "error": f"{type(e).__name__}: {e}",
                "exception": True,
            }
        summary["index"] = job.index
        if summary["success"]:
            ep.meta["collect_fingerprint"] = self.fingerprint
            EpisodeStore(cfg.out).write(ep, index=job.index)
        else:
            summary["error"] = f"no success within {cfg.max_steps} steps"
        return summary

    def close(self) -> None:
        self.envs.close()


# ----- the scheduler ----------------------------------------------------------------------------------------
@dataclass
class TaskProgress:
    task: str
    slot: int
    wanted: int
    successes: list[int] = field(default_factory=list)  # seeds
    resumed: list[int] = field(default_factory=list)  # seeds already in the store
    failures: dict[int, str] = field(default_factory=dict)  # seed -> reason
    next_seed: int = 0
    pending: int = 0
    frames: int = 0

    @property
    def done(self) -> int:
        return len(self.successes) + len(self.resumed)


class Scheduler:
    """Which seeds to roll out: per task, seeds from seed_base on while fewer than `episodes` succeeded or
    are running, up to episodes + max_failures seeds; seeds already in the store are resumed (after checking
    that they hold this task and seed, made with these settings), seeds that failed before with the same
    settings are skipped (rollouts are deterministic)."""

    def __init__(self, cfg: CollectConfig, store: EpisodeStore, failed_before: set[tuple[str, int]]):
        self.cfg, self.store, self.failed_before = cfg, store, failed_before
        self.collector = make_collector(cfg.env)
        self.fingerprint = fingerprint(cfg)
        self.progress = [
            TaskProgress(t, slot, cfg.episodes, next_seed=cfg.seed_base) for slot, t in enumerate(cfg.tasks)
        ]
        self.by_task = {tp.task: tp for tp in self.progress}
        self.new_frames = self.new_episodes = 0

    def initial_jobs(self) -> list[RolloutJob]:
        return [job for tp in self.progress for job in self.next_jobs(tp)]

    def next_jobs(self, tp: TaskProgress) -> list[RolloutJob]:
        cfg = self.cfg
        jobs = []
        last = collect_seeds(cfg).stop
        while tp.done + tp.pending < tp.wanted and tp.next_seed < last:
            seed = tp.next_seed
            tp.next_seed += 1
            index = episode_index(tp.slot, seed, cfg.seed_base)
            if index in self.store:
                self._resume(tp, seed, index)
            elif (tp.task, seed) in self.failed_before:
                tp.failures[seed] = "failed before with the same settings (skipped)"
            else:
                tp.pending += 1
                jobs.append(RolloutJob(tp.task, seed, index))
        return jobs

    def _resume(self, tp: TaskProgress, seed: int, index: int) -> None:
        """Count the stored episode `index` of (tp.task, seed); CollectError if it holds anything else."""
        meta = self.store.meta(index)
        task = self.collector.episode_task(tp.task)
        if meta.get("task") != task or meta.get("seed") != seed:
            raise CollectError(
                f"{self.cfg.out}: episode {index} holds task {meta.get('task')!r} seed {meta.get('seed')}, but "
                f"this collection would put {task!r} seed {seed} there; use the same tasks and seed_base "
                "as before, or a new --out"
            )
        if meta.get("collect_fingerprint") != self.fingerprint:
            raise CollectError(
                f"{self.cfg.out}: episode {index} was collected with other settings "
                f"({', '.join(FINGERPRINT_FIELDS)}); use the same settings to resume, or a new --out"
            )
        tp.resumed.append(seed)
        tp.frames += int(meta["length"])

    def record(self, summary: dict[str, Any]) -> list[RolloutJob]:
        """Count a finished rollout; returns the jobs that replace it."""
        tp = self.by_task[summary["task"]]
        tp.pending -= 1
        if summary["success"]:
            tp.successes.append(summary["seed"])
            tp.frames += summary["steps"]
            self.new_frames += summary["steps"]
            self.new_episodes += 1
        else:
            tp.failures[summary["seed"]] = summary.get("error", "failed")
        return self.next_jobs(tp)

    @property
    def failures(self) -> int:
        return sum(len(tp.failures) for tp in self.progress)

    def tasks_report(self) -> dict[str, dict[str, Any]]:
        seed_base = self.cfg.seed_base
        return {
            tp.task: {
                "wanted": tp.wanted,
                "episodes": tp.done,
                "new": len(tp.successes),
                "resumed": len(tp.resumed),
                "failed_seeds": {str(k): v for k, v in sorted(tp.failures.items())},
                "frames": tp.frames,
                "indices": sorted(episode_index(tp.slot, s, seed_base) for s in tp.successes + tp.resumed),
            }
            for tp in self.progress
        }


# ----- a collection -----------------------------------------------------------------------------------------
@dataclass
class CollectReport:
    tasks: dict[str, dict[str, Any]]
    seconds: float
    new_episodes: int
    new_frames: int
    complete: bool

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["frames_per_s"] = self.new_frames / self.seconds if self.seconds > 0 else 0.0
        d["episodes_per_s"] = self.new_episodes / self.seconds if self.seconds > 0 else 0.0
        return d


def attempt_key(task: str, seed: int, fp: str) -> str:
    """An attempt's key in the attempts log: the same (task, seed) with the same settings."""
    return json.dumps([task, seed, fp])


def failed_before(attempts: ResumeLog, fp: str) -> set[tuple[str, int]]:
    """(task, seed) of the logged rollouts that failed with settings `fp` (errors are retried)."""
    return {
        (r["task"], r["seed"])
        for r in attempts.read().values()
        if not r["success"] and r.get("fingerprint") == fp and not r.get("exception")
    }


def _run(cfg: CollectConfig, scheduler: Scheduler, attempts: ResumeLog, workers: int) -> None:
    """Roll out the scheduler's jobs in `workers` processes until it wants no more, logging every attempt;
    episodes kept of those wanted, with the rate and ETA, on stderr (`gazereg.runtime.progress`)."""
    initial = scheduler.initial_jobs()
    resumed = sum(len(tp.resumed) for tp in scheduler.progress)
    wanted = cfg.episodes * len(cfg.tasks)
    with Progress(f"collect {cfg.out}", wanted, "episodes", done=resumed, enabled=cfg.progress) as bar:
        worker = functools.partial(CollectWorker, cfg)
        with WorkerPool(worker, workers, child_environ=SINGLE_THREADED) as pool:
            for job in initial:
                pool.submit(job, tag=job)
            for _, summary in pool.results():
                attempts.append(
                    attempt_key(summary["task"], summary["seed"], scheduler.fingerprint),
                    {**summary, "fingerprint": scheduler.fingerprint},
                )
                for job in scheduler.record(summary):
                    pool.submit(job, tag=job)
                if summary["success"]:
                    bar.update(1)
                else:
                    bar.note(failed=scheduler.failures)


def collect(cfg: CollectConfig) -> CollectReport:
    """Run a collection (resuming a previous one in the same store); returns the report (also on disk).
    The settings were checked when `cfg` was built; `resolve` checks what the simulator refuses. Temporaries
    that killed writers left in the store are removed first."""
    cfg = resolve(cfg)
    sweep_stale_temps(cfg.out)
    store = EpisodeStore(cfg.out, create=True)
    log_dir = Path(cfg.out) / "collect"
    save_config(cfg, log_dir / "config.json")
    attempts = ResumeLog(log_dir / "attempts.jsonl")
    scheduler = Scheduler(cfg, store, failed_before(attempts, fingerprint(cfg)))
    workers = cfg.workers or available_cores()
    t0 = time.perf_counter()
    _run(cfg, scheduler, attempts, workers)
    report = CollectReport(
        tasks=scheduler.tasks_report(),
        seconds=time.perf_counter() - t0,
        new_episodes=scheduler.new_episodes,
        new_frames=scheduler.new_frames,
        complete=all(tp.done >= tp.wanted for tp in scheduler.progress),
    )
    info = {**report.to_dict(), "workers": workers, "fingerprint": scheduler.fingerprint}
    atomic_write_json(log_dir / "report.json", info)
    return report


# ----- the command line -------------------------------------------------------------------------------------
def _split_lists(argv: Sequence[str], options: Sequence[str] = ("--tasks", "--cameras")) -> list[str]:
    """Accept comma-separated lists: `--tasks a,b` and `--tasks=a,b` become `--tasks a b`."""
    out: list[str] = []
    in_list = False
    for arg in argv:
        name, eq, value = arg.partition("=")
        if arg.startswith("--") and name in options and eq:
            out += [name, *filter(None, value.split(","))]
            in_list = True
        elif arg.startswith("-"):
            out.append(arg)
            in_list = arg in options
        elif in_list:
            out += list(filter(None, arg.split(",")))
        else:
            out.append(arg)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    cfg = parse(
        PRESETS,
        _split_lists(argv),
        prog="gazereg collect",
        description=__doc__.split("\n\n")[0],
        default=DEFAULT_PRESET,
    )
    report = collect(cfg)
    d = report.to_dict()
    print(
        f"collected {report.new_episodes} new episodes ({report.new_frames} frames) in {report.seconds:.1f} s "
        f"({d['frames_per_s']:.0f} frames/s) into {cfg.out}"
    )
    for task, r in report.tasks.items():
        line = f"  {task:<28} {r['episodes']}/{r['wanted']} episodes ({r['resumed']} resumed), {r['frames']} frames"
        if r["failed_seeds"]:
            line += f"; failed seeds: {', '.join(r['failed_seeds'])}"
        print(line)
    if not report.complete:
        raise CollectionIncomplete(
            "some tasks have fewer episodes than asked for: raise --max-failures or --max-steps "
            f"(details: {Path(cfg.out) / 'collect' / 'report.json'})"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
