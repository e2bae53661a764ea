"""The scripted expert's success on Gym-Aloha setups, without rendering (the Aloha lane's venv):

    bash scripts/aloha_lane.sh --run python -m gazereg.envs.aloha.measure --seeds 0 50 --out expert.json

Prints, per task, successes out of setups and, for each failure, the highest reward the episode reached
(gym-aloha's stages: transfer 1 right gripper touches the cube, 2 lifts it, 3 left gripper touches it on the
table; insertion 1 both grippers touch, 2 both lift, 3 peg touches socket, 4 peg touches the pin); `--out`
writes the same as JSON.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from gazereg.envs.aloha.env import AlohaEnv
from gazereg.envs.aloha.expert import AlohaExpert
from gazereg.envs.aloha.setup import TASKS, resolve_task
from gazereg.runtime.errors import UsageError
from gazereg.runtime.io import atomic_write_json


def measure(task: str, seeds: Sequence[int]) -> dict:
    """{"task", "setups", "successes", "failures": [{"seed", "max_reward", "steps"}], "steps_to_success"}"""
    env = AlohaEnv(task, cameras=())
    failures, steps = [], []
    for seed in seeds:
        env.reset(seed=seed)
        expert = AlohaExpert()
        expert.reset(env, seed)
        best, info = 0.0, {"success": False}
        for _ in range(env.max_steps):
            _, reward, terminated, _, info = env.step(expert(env))
            best = max(best, reward)
            if terminated:
                break
        if info["success"]:
            steps.append(int(info["steps"]))
        else:
            failures.append({"seed": int(seed), "max_reward": best, "steps": int(info["steps"])})
    env.close()
    return {
        "task": task,
        "setups": [int(seeds[0]), int(seeds[-1])] if len(seeds) else [],
        "n": len(seeds),
        "successes": len(steps),
        "failures": failures,
        "steps_to_success": {"min": min(steps, default=0), "max": max(steps, default=0)},
    }


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m gazereg.envs.aloha.measure", description=__doc__.split("\n\n")[0]
    )
    ap.add_argument("--tasks", nargs="+", default=list(TASKS))
    ap.add_argument("--seeds", nargs=2, type=int, default=(0, 50), metavar=("FIRST", "COUNT"))
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    try:
        tasks = [resolve_task(t).name for t in args.tasks]
        first, count = args.seeds
        if first < 0 or count < 1:
            raise UsageError(f"--seeds takes FIRST >= 0 and COUNT >= 1, got {first} {count}")
    except (KeyError, UsageError) as e:
        print(f"{ap.prog}: error: {e.args[0]}", file=sys.stderr)
        return 2
    results = []
    for task in tasks:
        t0 = time.perf_counter()
        r = measure(task, list(range(first, first + count)))
        r["seconds"] = round(time.perf_counter() - t0, 1)
        results.append(r)
        why = ", ".join(f"seed {f['seed']}: reward {f['max_reward']:g}" for f in r["failures"]) or "none"
        print(
            f"{task}: {r['successes']}/{r['n']} on setups {first}..{first + count - 1} ({r['seconds']} s); failed: {why}"
        )
    if args.out:
        atomic_write_json(
            args.out, {"command": " ".join(["measure", *map(str, argv or sys.argv[1:])]), "results": results}
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
