"""LIBERO env steps/s with two 128x128 cameras (agentview + wrist), and the scripted expert's success per task.

    bash scripts/libero_env.sh python benchmarks/bench_libero.py [--steps 200] [--suite libero_spatial]
    bash scripts/libero_env.sh python benchmarks/bench_libero.py --expert-inits 5 [--expert-noise 0.1]
    bash scripts/libero_env.sh python benchmarks/bench_libero.py --suite libero_object --expert-inits 20 \
        --out docs/benchmarks/libero_object_expert.json
    bash scripts/libero_env.sh python benchmarks/bench_libero.py --suite libero_goal --expert-inits 10 \
        --expert-max-steps 300 --out docs/benchmarks/libero_goal_expert.json
    bash scripts/libero_env.sh python benchmarks/bench_libero.py --expert-inits 50 --tasks 6 \
        --expert-max-steps 400

Needs the LIBERO venv (scripts/libero_env.sh); elsewhere prints {"skipped": "..."} and exits 0. Times zero
actions (arm still) on one task, excluding build and reset, plus physics-only steps (no cameras) for
comparison, with the render copy's simplified meshes (LiberoEnv's default) and with the full meshes, and the
time of a reset. `--expert-inits N` instead rolls the suite's scripted expert (`make_expert`: SpatialExpert,
ObjectExpert, GoalExpert) out on initial states 0..N-1 of every task of `--suite` (physics only, no cameras:
the expert reads object poses) and reports successes, failed initial states (each with the expert's phase and
retries when it stopped: a failure in `carry` or later had the object in hand), episode lengths and wall time
per task; `--tasks` only those of the suite's tasks.
Prints one JSON object; `--out PATH` also writes it there (atomically), with the machine line.
`--markdown JSON` measures nothing: it prints an expert JSON's table for docs (no LIBERO needed).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from _timing import emit, machine_info, print_markdown


def run(
    suite: str, steps: int, cameras: tuple[str, ...], size: int, mesh_cell: object = "auto"
) -> dict[str, float]:
    import numpy as np

    from gazereg.envs.libero.env import LiberoEnv

    t0 = time.perf_counter()
    env = LiberoEnv(
        suite,
        cameras=cameras,
        image_size=size,
        max_steps=10**6,
        terminate_on_success=False,
        mesh_cell=mesh_cell,
    )
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


def expert_report(
    suite: str, task_ids: Sequence[int], inits: int, noise: float, max_steps: int
) -> dict[str, object]:
    """The suite's expert (`make_expert`) on initial states 0..inits-1 of each of its tasks `task_ids` (LIBERO
    imported already: `import_libero`)."""
    from gazereg.envs.libero.collector import make_expert
    from gazereg.envs.libero.env import LiberoEnv
    from gazereg.envs.recording import noise_seed

    tasks = {}
    t_all = time.perf_counter()
    for t in task_ids:
        env = LiberoEnv(f"{suite}/{t}", cameras=(), max_steps=max_steps)
        t0 = time.perf_counter()
        ok, lengths, failed, phases = 0, [], [], []
        for k in range(inits):
            env.reset(seed=k)
            expert = make_expert(suite, noise)
            expert.reset(env, noise_seed(env.task, k))
            for step in range(1, max_steps + 1):  # noqa: B007 (step is the episode length)
                _, _, terminated, truncated, info = env.step(expert(env))
                if terminated or truncated:
                    break
            if info["success"]:
                ok += 1
                lengths.append(step)
            else:
                failed.append(k)
                phases.append({"phase": expert.phase, "retries": expert.regrasps})
        tasks[env.task_names[t]] = {
            "task": f"{suite}/{t}",
            "instruction": env.instruction,
            "successes": ok,
            "n": inits,
            "failed_init_states": failed,
            "failed_phases": phases,
            "mean_length": sum(lengths) / len(lengths) if lengths else None,
            "max_length": max(lengths) if lengths else None,
            "seconds": time.perf_counter() - t0,
        }
        env.close()
        print(f"{env.task_names[t]}: {ok}/{inits}", file=sys.stderr, flush=True)
    total = sum(v["successes"] for v in tasks.values())
    return {
        "suite": suite,
        "expert": type(expert).__name__,
        "init_states": list(range(inits)),
        "action_noise": noise,
        "max_steps": max_steps,
        "successes": total,
        "n": len(tasks) * inits,
        "seconds": time.perf_counter() - t_all,
        "tasks": tasks,
    }


def expert_markdown(result: dict, source: str) -> str:
    """An expert JSON (`--expert-inits`) as a line naming the run and a per-task markdown table."""
    m = result["machine"]
    lines = [
        f"{result['expert']} on initial states {result['init_states'][0]}..{result['init_states'][-1]} of "
        f"{result['suite']}, at most {result['max_steps']} steps, action noise {result['action_noise']}: "
        f"{result['successes']}/{result['n']}; {m['cpu_model']}, {m['cores']} cores, load average before "
        f"{m['load_avg_before'][0]}; from `{source}`:",
        "",
        "| task | instruction | successes | mean steps | longest | failed initial states |",
        "|---|---|---|---|---|---|",
    ]
    for r in sorted(result["tasks"].values(), key=lambda r: int(r["task"].rsplit("/", 1)[1])):
        failed = ", ".join(map(failure, r["failed_init_states"], r.get("failed_phases", [None] * r["n"])))
        mean = "-" if r["mean_length"] is None else f"{r['mean_length']:.0f}"  # no success: no length
        longest = "-" if r["max_length"] is None else r["max_length"]
        lines.append(
            f"| {r['task']} | {r['instruction']} | {r['successes']}/{r['n']} | {mean} | {longest} | "
            f"{failed or 'none'} |"
        )
    return "\n".join(lines)


def failure(state: int, phase: dict | None) -> str:
    """A failed initial state, with the expert's phase when it stopped (and its retries) where recorded."""
    if phase is None:
        return str(state)
    retries = {0: "", 1: ", 1 retry"}.get(phase["retries"], f", {phase['retries']} retries")
    return f"{state} ({phase['phase']}{retries})"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--suite", default="libero_spatial")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--expert-inits", type=int, default=0, help="report the expert on this many init states")
    ap.add_argument("--expert-noise", type=float, default=0.0)
    ap.add_argument("--expert-max-steps", type=int, default=300)
    ap.add_argument(
        "--tasks", type=int, nargs="+", default=None, metavar="T", help="--expert-inits: only these task ids"
    )
    ap.add_argument("--out", type=Path, default=None, help="also write the JSON here")
    ap.add_argument(
        "--markdown", type=Path, default=None, metavar="JSON", help="print an expert JSON's table"
    )
    args = ap.parse_args()
    if args.markdown is not None:
        return print_markdown(args.markdown, expert_markdown, "bench_libero.py")
    if args.out is not None and not args.out.parent.is_dir():
        ap.error(f"--out: the folder {args.out.parent} does not exist")
    from gazereg.envs.libero.setup import libero_available

    ok, why = libero_available()
    if not ok:
        print(json.dumps({"benchmark": "libero", "skipped": why}))
        return 0
    if args.expert_inits > 0:
        from gazereg.envs.libero.collector import EXPERTS
        from gazereg.envs.libero.setup import import_libero, suite_benchmark

        if args.suite not in EXPERTS:
            ap.error(f"--suite {args.suite}: no scripted expert (experts: {', '.join(EXPERTS)})")
        import_libero(None)  # LIBERO's config, without its prompts
        n_tasks = len(suite_benchmark(args.suite).get_task_names())
        if args.tasks is not None and not all(0 <= t < n_tasks for t in args.tasks):
            ap.error(f"--tasks {args.tasks}: {args.suite} has tasks 0..{n_tasks - 1}")
        task_ids = range(n_tasks) if args.tasks is None else args.tasks
        machine = machine_info()  # before the run: its load average is the one the run started under
        report = expert_report(
            args.suite, task_ids, args.expert_inits, args.expert_noise, args.expert_max_steps
        )
        emit({"benchmark": "libero_expert", "machine": machine, **report}, args.out)
        return 0
    from gazereg.envs.render import select_gl_backend

    out = {
        "benchmark": "libero",
        "machine": machine_info(),
        "suite": args.suite,
        "steps": args.steps,
        "image_size": args.size,
        "gl_backend": select_gl_backend(),
        "load_avg_before": os.getloadavg()[0],
        "two_cameras": run(args.suite, args.steps, ("agentview", "robot0_eye_in_hand"), args.size),
        # the same with robosuite's full meshes (no simplified render copy): the speed before it
        "two_cameras_full_meshes": run(
            args.suite, args.steps, ("agentview", "robot0_eye_in_hand"), args.size, mesh_cell=None
        ),
        "physics_only": run(args.suite, args.steps, (), args.size),
        "load_avg_after": os.getloadavg()[0],
    }
    emit(out, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
