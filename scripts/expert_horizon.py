"""Can the evaluation's step limit be met at all? Rolls Meta-World's scripted expert out on a preset's
evaluation setups (its tasks, `eval.seed_start` and `eval.episodes`), physics only, with a long step limit,
and prints per task the expert's successes within the preset's limit and within the long one, and the steps
its successes took. A task whose expert needs more steps than the preset allows would fail every arm for
reasons no policy can change (issue #21, item 2, for the task sweep).

    python scripts/expert_horizon.py --preset sweep                 # 500 steps, the sweep's 50 setups per task
    python scripts/expert_horizon.py --preset paper --episodes 20 --out runs/expert_horizon.md
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from gazereg.envs.metaworld.env import MetaWorldEnv
from gazereg.envs.metaworld.experts import Expert
from gazereg.envs.recording import noise_seed, record_rollout
from gazereg.experiment.config import PRESETS
from gazereg.runtime.io import atomic_write_text


def expert_lengths(task: str, seeds: range, max_steps: int) -> list[int | None]:
    """Steps to success of the scripted expert on each setup seed of `task` (None: no success in `max_steps`)."""
    env = MetaWorldEnv(task, cameras=(), max_steps=max_steps, render_mode=None)
    expert = Expert(task)
    out: list[int | None] = []
    for seed in seeds:
        expert.reset(noise_seed(task, seed))
        rec = record_rollout(env, lambda obs, info: expert(env.raw_obs), seed, max_steps)
        out.append(rec.length if rec.success else None)
    env.close()
    return out


def table(lengths: dict[str, list[int | None]], limit: int, max_steps: int) -> list[str]:
    """A markdown table: per task the setups, successes within `limit` and `max_steps`, median and max steps."""
    lines = [
        f"| task | setups | expert success within {limit} | within {max_steps} | median steps | max steps |",
        "|---|---|---|---|---|---|",
    ]
    for task, xs in lengths.items():
        ok = [x for x in xs if x is not None]
        median = f"{statistics.median(ok):.0f}" if ok else "-"
        longest = str(max(ok)) if ok else "-"
        within = sum(x <= limit for x in ok)
        lines.append(f"| {task} | {len(xs)} | {within} | {len(ok)} | {median} | {longest} |")
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="sweep", choices=sorted(PRESETS))
    ap.add_argument("--max-steps", type=int, default=500, help="the long step limit (Meta-World's standard)")
    ap.add_argument("--episodes", type=int, default=None, help="setups per task (default: the preset's)")
    ap.add_argument("--out", type=Path, default=None, help="also write the markdown here")
    args = ap.parse_args()
    cfg = PRESETS[args.preset]()
    if cfg.env != "metaworld":
        raise SystemExit(f"--preset {args.preset} runs {cfg.env}; this script rolls out Meta-World's experts")
    episodes = args.episodes or cfg.eval.episodes
    if episodes < 1 or args.max_steps < cfg.eval.max_steps:
        raise SystemExit(f"need --episodes >= 1 and --max-steps >= the preset's {cfg.eval.max_steps}")
    seeds = range(cfg.eval.seed_start, cfg.eval.seed_start + episodes)
    t0 = time.perf_counter()
    lengths = {task: expert_lengths(task, seeds, args.max_steps) for task in cfg.tasks}
    lines = [
        f"## Scripted expert on the `{args.preset}` preset's evaluation setups (seeds {seeds.start}..{seeds.stop - 1})",
        "",
        *table(lengths, cfg.eval.max_steps, args.max_steps),
        "",
        f"Command: `python scripts/expert_horizon.py --preset {args.preset} --max-steps {args.max_steps}"
        f"{f' --episodes {args.episodes}' if args.episodes else ''}`; wall time {time.perf_counter() - t0:.0f} s.",
    ]
    text = "\n".join(lines) + "\n"
    print(text, end="")
    if args.out:
        atomic_write_text(args.out, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
