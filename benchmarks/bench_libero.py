"""LIBERO env steps/s with two 128x128 cameras (agentview + wrist), gazevla's fast render settings.

    bash scripts/libero_env.sh python benchmarks/bench_libero.py [--steps 200] [--suite libero_spatial]

Needs the LIBERO venv (scripts/libero_env.sh); elsewhere prints {"skipped": "..."} and exits 0. Times zero
actions (arm still) on one task, excluding build and reset, plus physics-only steps (no cameras) for
comparison, and the time of a reset. Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import time


def run(suite: str, steps: int, cameras: tuple[str, ...], size: int) -> dict[str, float]:
    import numpy as np

    from gazevla.envs.libero import LiberoEnv

    t0 = time.perf_counter()
    env = LiberoEnv(suite, cameras=cameras, image_size=size, max_steps=10**6, terminate_on_success=False)
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    env.reset(seed=0)
    first_reset = time.perf_counter() - t0
    t0 = time.perf_counter()
    env.reset(seed=10)  # same task, next initial state
    reset = time.perf_counter() - t0
    a = np.zeros(7)
    for _ in range(10):  # warm-up
        env.step(a)
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        env.step(a)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    env.close()
    return {
        "steps_per_s": steps / wall,
        "cpu_ms_per_step": 1000 * cpu / steps,
        "build_s": build,
        "first_reset_s": first_reset,
        "reset_s": reset,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--suite", default="libero_spatial")
    ap.add_argument("--size", type=int, default=128)
    args = ap.parse_args()
    from gazevla.envs.libero import libero_available

    ok, why = libero_available()
    if not ok:
        print(json.dumps({"benchmark": "libero", "skipped": why}))
        return 0
    from gazevla.envs.render import select_gl_backend

    out = {
        "benchmark": "libero",
        "suite": args.suite,
        "steps": args.steps,
        "image_size": args.size,
        "gl_backend": select_gl_backend(),
        "load_avg_before": os.getloadavg()[0],
        "two_cameras": run(args.suite, args.steps, ("agentview", "robot0_eye_in_hand"), args.size),
        "physics_only": run(args.suite, args.steps, (), args.size),
        "load_avg_after": os.getloadavg()[0],
    }
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
