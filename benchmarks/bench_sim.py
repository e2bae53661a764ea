"""Simulation speed: Meta-World env steps/s with and without rendering, and demonstration collection throughput.

    python benchmarks/bench_sim.py [--steps 600] [--episodes 30] [--workers 2]

Env steps are timed in this process pinned to one core (the GL renderer's threads too), with Meta-World's
scripted expert acting (pick-place-v3, the episode restarting when it ends), for: physics only; one camera at
128x128 and 96x96 with gazereg's render settings; and 128x128 with the original meshes (no simplification),
for comparison. Collection runs `gazereg.envs.collect` with `--workers` processes on every core. Prints one
JSON object, including the machine's load average before and after (other jobs on the machine slow it down;
the CPU time per step / frame does not depend on them).
The OpenGL backend is chosen by `gazereg.envs.render.select_gl_backend` and passed explicitly.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from _timing import machine_info


def env_steps_per_s(task: str, steps: int, gl_backend: str, **env_kwargs) -> dict[str, float]:
    from gazereg.envs import Expert, MetaWorldEnv

    env = MetaWorldEnv(task, max_steps=500, terminate_on_success=False, gl_backend=gl_backend, **env_kwargs)
    expert = Expert(task)
    env.reset(seed=0)
    for _ in range(20):  # warm-up
        env.step(expert(env.raw_obs))
    seed, n, resets, reset_s = 1, 0, 0, 0.0
    t0, c0 = time.perf_counter(), time.process_time()
    env.reset(seed=seed)
    while n < steps:
        _, _, _, truncated, info = env.step(expert(env.raw_obs))
        n += 1
        if info["success"] or truncated:  # a fresh setup, as an evaluation loop would do
            seed += 1
            r0 = time.perf_counter()
            env.reset(seed=seed)
            reset_s += time.perf_counter() - r0
            resets += 1
    total = time.perf_counter() - t0
    cpu = time.process_time() - c0
    env.close()
    return {
        "steps_per_s": n / total,
        "steps_per_s_excluding_resets": n / (total - reset_s),
        "reset_ms": 1000 * reset_s / max(resets, 1),
        "cpu_ms_per_step": 1000 * cpu / n,
        "steps": n,
    }


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--task", default="pick-place-v3")
    ap.add_argument(
        "--episodes", type=int, default=30, help="collection: episodes per task (the quick preset)"
    )
    ap.add_argument("--tasks", default="reach-v3,button-press-topdown-v3,pick-place-v3")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--image-size", type=int, default=96, help="collection image size")
    return ap.parse_args()


def env_rates_one_core(task: str, steps: int, backend: str) -> dict[str, float]:
    """Environment steps/s on one core: physics only, rendering at 128 and 96 px, full meshes, two cameras."""
    all_cores = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(all_cores)})  # one core, before any GL context spawns its threads
    try:
        return {
            "physics_only": env_steps_per_s(task, steps * 3, backend, cameras=()),
            "render_128": env_steps_per_s(task, steps, backend, cameras=("corner2",), image_size=128),
            "render_96": env_steps_per_s(task, steps, backend, cameras=("corner2",), image_size=96),
            "render_128_full_meshes": env_steps_per_s(
                task, steps // 2, backend, cameras=("corner2",), image_size=128, mesh_cell=None
            ),
            "render_128_two_cameras": env_steps_per_s(
                task, steps // 2, backend, cameras=("corner2", "topview"), image_size=128
            ),
        }
    finally:
        os.sched_setaffinity(0, all_cores)


def collection_rates(
    tasks: tuple[str, ...], episodes: int, image_size: int, workers: int, backend: str
) -> dict:
    """`gazereg collect`'s throughput: wall-clock frames/s, and per-worker rates from the rollouts' own times."""
    from gazereg.envs.collect import collect
    from gazereg.envs.collect_config import CollectConfig

    with tempfile.TemporaryDirectory() as tmp:
        cfg = CollectConfig(
            out=Path(tmp) / "demos",
            tasks=tasks,
            episodes=episodes,
            image_size=image_size,
            cameras=("corner2",),
            workers=workers,
            progress=False,
            gl_backend=backend,
        )
        t0 = time.perf_counter()
        report = collect(cfg)
        wall = time.perf_counter() - t0
        attempts = [
            json.loads(x)["record"]
            for x in (Path(tmp) / "demos" / "collect" / "attempts.jsonl").read_text().splitlines()
        ]
    rollout_s = sum(a["seconds"] for a in attempts)
    rollout_cpu = sum(a.get("cpu_seconds", 0.0) for a in attempts)
    return {
        "tasks": list(tasks),
        "image_size": image_size,
        "workers": workers,
        "episodes": report.new_episodes,
        "frames": report.new_frames,
        "wall_s": wall,
        "frames_per_s": report.new_frames / wall,
        "episodes_per_s": report.new_episodes / wall,
        "complete": report.complete,
        "rollout_frames_per_s_per_worker": report.new_frames / rollout_s,
        "cpu_ms_per_frame": 1000 * rollout_cpu / report.new_frames,
        "frames_per_s_if_cores_idle": workers * report.new_frames / rollout_cpu,
        "note": "wall time includes starting the worker processes and building each task's environment; "
        "rollout_frames_per_s_per_worker counts only the time inside rollouts (steady state of one worker); "
        "frames_per_s_if_cores_idle = workers / CPU time per frame, what the rollouts would reach with every core "
        "to themselves (the machine is shared: see load_avg)",
    }


def main() -> int:
    args = parse_args()
    from gazereg.envs.render import select_gl_backend
    from gazereg.runtime.pool import available_cores

    backend = select_gl_backend()
    result: dict = {
        "machine": machine_info(cores=available_cores()),
        "gl_backend": backend,
        "task": args.task,
    }
    result["env_one_core"] = env_rates_one_core(args.task, args.steps, backend)
    tasks = tuple(t for t in args.tasks.split(",") if t)
    result["collect"] = collection_rates(tasks, args.episodes, args.image_size, args.workers, backend)
    result["machine"]["load_avg_after"] = os.getloadavg()
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
