"""`gazereg collect`: roll out scripted experts (Meta-World's, or gazereg's LIBERO-Spatial expert) into a store.

    gazereg collect --preset smoke
    gazereg collect --tasks reach-v3,pick-place-v3 --episodes 5 --out runs/demos
    gazereg collect --tasks reach-v3 pick-place-v3 --episodes 5 --cameras corner2 topview --image-size 128
    bash scripts/libero_env.sh gazereg collect --env libero --tasks libero_spatial/0 --episodes 5 --out runs/lib

`--env libero` (in the LIBERO venv, scripts/libero_env.sh) takes LIBERO tasks (`libero_spatial` for all 10
tasks of the suite, `libero_spatial/3`, `libero_spatial/<task name>`) and rolls out
`gazereg.envs.libero.expert.SpatialExpert` on their fixed initial states (seed s = initial state s % 50); its
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
camera geometry, settings. Workers: one process per core by default, each with its own environment.
The per-simulator parts (tasks, environments, the rollout) are collector objects: `SIMULATORS`.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import hashlib
import json
import multiprocessing as mp
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from gazereg.data.store import EpisodeStore
from gazereg.envs.recording import rollout_expert  # noqa: F401  (re-exported: gazereg.envs.collect.rollout_expert)
from gazereg.runtime.io import append_jsonl, atomic_write_json

# simulator -> "module:attribute" of its collector (imported only when used); see rollout.MetaWorldCollector
SIMULATORS = {
    "metaworld": "gazereg.envs.recording:MetaWorldCollector",
    "libero": "gazereg.envs.libero.expert:LiberoCollector",
}
INDEX_STRIDE = 1000  # episode indices per task slot
MAX_INDEX = 999_999  # the store names episodes with 6 digits


class CollectError(ValueError):
    """A collection that cannot run as configured (unknown task, a store made with other settings, ...)."""


@dataclass(frozen=True)
class CollectConfig:
    """Expert demonstrations in simulation (Meta-World or LIBERO), written to an episode store."""

    out: Path = Path("runs/quick/demos")
    """The episode store (created if missing)."""
    tasks: tuple[str, ...] = ("reach-v3", "button-press-topdown-v3", "pick-place-v3")
    """Meta-World v3 task names, or LIBERO tasks with --env libero (commas or spaces between them)."""
    episodes: int = 30
    """Successful episodes wanted per task."""
    seed_base: int = 0
    """First setup seed; seeds 0-49 are Meta-World's 50 MT1 setups of benchmark seed 0."""
    max_failures: int = 20
    """Extra seeds tried per task to replace failed rollouts."""
    cameras: tuple[str, ...] = ()
    """Cameras to render; empty = the simulator's default (Meta-World: corner2; LIBERO: agentview_rgb
    eye_in_hand_rgb). Meta-World: corner, corner2, corner3, corner4, topview, behindGripper, gripperPOV."""
    image_size: int = 96
    """Square image side in pixels."""
    action_noise: float = 0.0
    """Std of Gaussian noise added to the expert's actions (action units; actions are clipped to [-1, 1])."""
    max_steps: int = 0
    """A rollout that has not succeeded after this many steps is a failure; 0 = the simulator's default
    (Meta-World 200, LIBERO 220, the LIBERO-Spatial evaluation length)."""
    goal_marker_radius: float = 0.03
    """Radius (m) of the rendered goal sphere (rendering only); 0 keeps Meta-World's own marker."""
    perturbation: str = ""
    """Meta-World: render under this perturbation (gazereg.envs.perturbations spec, e.g. dim:0.7): the same
    setups and expert actions, seen under other light or with sensor noise; empty = clean."""
    workers: int = 0
    """Worker processes; 0 = one per available core."""
    gl_backend: str = ""
    """OpenGL backend (egl, osmesa); empty = MUJOCO_GL if set, else egl, else osmesa."""
    progress: bool = True
    """Show a progress bar."""
    env: Literal["metaworld", "libero"] = "metaworld"
    """Simulator: metaworld, or libero (needs the LIBERO venv: bash scripts/libero_env.sh gazereg collect ...)."""


PRESETS = {
    "quick": lambda: CollectConfig(),
    "smoke": lambda: CollectConfig(
        out=Path("runs/smoke/demos"),
        tasks=("reach-v3", "pick-place-v3"),
        episodes=2,
        max_failures=4,
        image_size=64,
        max_steps=150,
    ),
    "paper": lambda: CollectConfig(
        out=Path("runs/paper/demos"),
        tasks=(
            "reach-v3",
            "push-v3",
            "pick-place-v3",
            "door-open-v3",
            "drawer-open-v3",
            "drawer-close-v3",
            "button-press-topdown-v3",
            "peg-insert-side-v3",
            "window-open-v3",
            "window-close-v3",
        ),
        episodes=50,
        max_failures=50,
        cameras=("corner2", "corner3"),
        image_size=128,
        max_steps=300,
    ),
}

# Settings that change what an episode contains; episodes made with other values are not mixed in one store.
_FINGERPRINT_FIELDS = ("cameras", "image_size", "action_noise", "max_steps", "goal_marker_radius")


def fingerprint(cfg: CollectConfig) -> str:
    """Hash of the settings that change what an episode contains (of a resolved config)."""
    d = {k: getattr(cfg, k) for k in _FINGERPRINT_FIELDS}
    d["cameras"] = list(d["cameras"])
    if cfg.env != "metaworld":  # Meta-World stores made before there was a choice keep their fingerprint
        d["env"] = cfg.env
    if cfg.perturbation:  # likewise clean stores
        d["perturbation"] = cfg.perturbation
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


def episode_index(slot: int, seed: int, seed_base: int) -> int:
    return slot * INDEX_STRIDE + (seed - seed_base)


def available_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def collector(env: str) -> Any:
    """The collector of simulator `env` (see SIMULATORS); CollectError for an unknown one."""
    import importlib

    if env not in SIMULATORS:
        raise CollectError(f"unknown simulator {env!r}; choose one of {sorted(SIMULATORS)}")
    module, name = SIMULATORS[env].split(":")
    return getattr(importlib.import_module(module), name)()


def resolve(cfg: CollectConfig) -> CollectConfig:
    """Fill the simulator's defaults (cameras, max_steps) and canonical task names; CollectError if invalid."""
    sim = collector(cfg.env)
    try:
        tasks = sim.tasks(cfg.tasks)
    except (KeyError, ValueError) as e:
        raise CollectError(str(e.args[0]) if e.args else str(e)) from None
    return dataclasses.replace(
        cfg,
        tasks=tasks,
        cameras=tuple(cfg.cameras) or sim.default_cameras,
        max_steps=cfg.max_steps or sim.default_max_steps,
    )


# ----- workers ----------------------------------------------------------------------------------------------
_WORKER_ENVS: dict[tuple, Any] = {}  # environments kept per process, by task and render settings


def _worker_init() -> None:
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, "1")


def _env_for(task: str, cfg: CollectConfig) -> Any:
    """This process's environment for `task` and the render settings of `cfg` (a resolved config)."""
    key = (cfg.env, task, cfg.cameras, cfg.image_size, cfg.max_steps, cfg.goal_marker_radius, cfg.gl_backend)
    key += (cfg.perturbation,)
    if key not in _WORKER_ENVS:
        if len(_WORKER_ENVS) >= 8:  # a long-lived process (tests, notebooks) does not pile environments up
            oldest = next(iter(_WORKER_ENVS))
            _WORKER_ENVS.pop(oldest).close()
        _WORKER_ENVS[key] = collector(cfg.env).make_env(task, cfg)
    return _WORKER_ENVS[key]


def _run_job(cfg: CollectConfig, task: str, seed: int, index: int) -> dict[str, Any]:
    """Run one rollout in this process; write it to the store if it succeeded. Returns its summary."""
    env = _env_for(task, cfg)
    try:
        ep, summary = collector(cfg.env).rollout(env, seed, cfg.action_noise, cfg.max_steps)
    except Exception as e:  # a simulator error fails this seed, not the collection
        error = f"{type(e).__name__}: {e}"
        return {
            "task": task,
            "seed": seed,
            "index": index,
            "success": False,
            "steps": 0,
            "seconds": 0.0,
            "error": error,
            "exception": True,
        }
    summary["index"] = index
    if summary["success"]:
        ep.meta["collect_fingerprint"] = fingerprint(cfg)
        EpisodeStore(cfg.out).write(ep, index=index)
    else:
        summary["error"] = f"no success within {cfg.max_steps} steps"
    return summary


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


def _validate(cfg: CollectConfig) -> None:
    """Check a resolved config (see `resolve`)."""
    limit = collector(cfg.env).max_steps_limit
    if not cfg.tasks:
        raise CollectError("no tasks given")
    if len(set(cfg.tasks)) != len(cfg.tasks):
        raise CollectError(f"duplicate tasks in {cfg.tasks}")
    if cfg.episodes < 1 or cfg.max_failures < 0 or cfg.episodes + cfg.max_failures > INDEX_STRIDE:
        raise CollectError(f"need 1 <= episodes and episodes + max_failures <= {INDEX_STRIDE}")
    if len(cfg.tasks) * INDEX_STRIDE - 1 > MAX_INDEX:
        raise CollectError(f"at most {(MAX_INDEX + 1) // INDEX_STRIDE} tasks per store")
    if cfg.seed_base < 0:
        raise CollectError("seed_base must be >= 0")
    if not 1 <= cfg.max_steps <= limit:
        raise CollectError(f"max_steps must be in [1, {limit}]")
    if cfg.image_size < 8 or not cfg.cameras:
        raise CollectError("need at least one camera and image_size >= 8")
    if cfg.perturbation:
        from gazereg.envs.perturbations import parse_perturbation

        if cfg.env != "metaworld":
            raise CollectError(f"perturbation={cfg.perturbation!r}: only the metaworld simulator renders one")
        try:
            parse_perturbation(cfg.perturbation)
        except (KeyError, ValueError) as e:
            raise CollectError(f"perturbation={cfg.perturbation!r}: {e}") from None


def collect(cfg: CollectConfig) -> CollectReport:
    """Run a collection (resuming a previous one in the same store); returns the report (also on disk)."""
    from gazereg.runtime.config import save_config

    cfg = resolve(cfg)
    _validate(cfg)
    sim = collector(cfg.env)
    store = EpisodeStore(cfg.out, create=True)
    log_dir = Path(cfg.out) / "collect"
    save_config(cfg, log_dir / "config.json")
    attempts_path = log_dir / "attempts.jsonl"
    fp = fingerprint(cfg)
    failed_before: set[tuple[str, int]] = set()
    if attempts_path.exists():
        for line in attempts_path.read_text().splitlines():
            rec = json.loads(line)
            # Seeds that failed with the same settings fail again (rollouts are deterministic); errors are retried.
            if not rec["success"] and rec.get("fingerprint") == fp and not rec.get("exception"):
                failed_before.add((rec["task"], rec["seed"]))

    progress = [
        TaskProgress(t, slot, cfg.episodes, next_seed=cfg.seed_base) for slot, t in enumerate(cfg.tasks)
    ]
    limit = cfg.episodes + cfg.max_failures

    def next_jobs(tp: TaskProgress) -> list[tuple[str, int, int]]:
        jobs = []
        while tp.done + tp.pending < tp.wanted and tp.next_seed < cfg.seed_base + limit:
            seed = tp.next_seed
            tp.next_seed += 1
            index = episode_index(tp.slot, seed, cfg.seed_base)
            if index in store:
                meta = store.meta(index)
                if meta.get("task") != sim.episode_task(tp.task) or meta.get("seed") != seed:
                    raise CollectError(
                        f"{cfg.out}: episode {index} holds task {meta.get('task')!r} seed {meta.get('seed')}, but "
                        f"this collection would put {sim.episode_task(tp.task)!r} seed {seed} there; use the same tasks and seed_base "
                        "as before, or a new --out"
                    )
                if meta.get("collect_fingerprint") != fp:
                    raise CollectError(
                        f"{cfg.out}: episode {index} was collected with other settings ({', '.join(_FINGERPRINT_FIELDS)}); "
                        "use the same settings to resume, or a new --out"
                    )
                tp.resumed.append(seed)
                tp.frames += int(meta["length"])
            elif (tp.task, seed) in failed_before:
                tp.failures[seed] = "failed before with the same settings (skipped)"
            else:
                tp.pending += 1
                jobs.append((tp.task, seed, index))
        return jobs

    workers = cfg.workers or available_cores()
    by_task = {tp.task: tp for tp in progress}
    t0 = time.perf_counter()
    new_frames = 0
    new_episodes = 0
    bar = None
    if cfg.progress:
        from tqdm import tqdm

        bar = tqdm(total=cfg.episodes * len(cfg.tasks), desc="collect", unit="ep", file=sys.stderr)

    def handle(summary: dict[str, Any]) -> list[tuple[str, int, int]]:
        nonlocal new_frames, new_episodes
        tp = by_task[summary["task"]]
        tp.pending -= 1
        append_jsonl(attempts_path, {**summary, "fingerprint": fp})
        if summary["success"]:
            tp.successes.append(summary["seed"])
            tp.frames += summary["steps"]
            new_frames += summary["steps"]
            new_episodes += 1
            if bar is not None:
                bar.update(1)
        else:
            tp.failures[summary["seed"]] = summary.get("error", "failed")
            if bar is not None:
                bar.set_postfix(failed=sum(len(p.failures) for p in progress))
        return next_jobs(tp)

    initial = [job for tp in progress for job in next_jobs(tp)]
    if bar is not None:
        bar.update(sum(len(tp.resumed) for tp in progress))
    try:
        if workers <= 1:
            queue = list(initial)
            while queue:
                queue.extend(handle(_run_job(cfg, *queue.pop(0))))
        else:
            ctx = mp.get_context("spawn")  # fresh interpreters: no inherited GL or MuJoCo state
            with cf.ProcessPoolExecutor(
                max_workers=workers, mp_context=ctx, initializer=_worker_init
            ) as pool:
                running = {pool.submit(_run_job, cfg, *job) for job in initial}
                while running:
                    finished, running = cf.wait(running, return_when=cf.FIRST_COMPLETED)
                    for fut in finished:
                        for job in handle(fut.result()):
                            running.add(pool.submit(_run_job, cfg, *job))
    finally:
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - t0

    tasks_report = {}
    for tp in progress:
        tasks_report[tp.task] = {
            "wanted": tp.wanted,
            "episodes": tp.done,
            "new": len(tp.successes),
            "resumed": len(tp.resumed),
            "failed_seeds": {str(k): v for k, v in sorted(tp.failures.items())},
            "frames": tp.frames,
            "indices": sorted(episode_index(tp.slot, s, cfg.seed_base) for s in tp.successes + tp.resumed),
        }
    report = CollectReport(
        tasks=tasks_report,
        seconds=seconds,
        new_episodes=new_episodes,
        new_frames=new_frames,
        complete=all(tp.done >= tp.wanted for tp in progress),
    )
    atomic_write_json(log_dir / "report.json", {**report.to_dict(), "workers": workers, "fingerprint": fp})
    return report


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
    from gazereg.runtime.config import parse

    argv = list(sys.argv[1:] if argv is None else argv)
    cfg = parse(PRESETS, _split_lists(argv), prog="gazereg collect", description=__doc__.split("\n\n")[0])
    try:
        report = collect(cfg)
    except CollectError as e:
        print(f"gazereg collect: {e}", file=sys.stderr)
        return 2
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
        print(
            "some tasks have fewer episodes than asked for: raise --max-failures or --max-steps "
            f"(details: {Path(cfg.out) / 'collect' / 'report.json'})",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
