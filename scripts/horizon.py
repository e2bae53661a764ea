"""Does a longer horizon add success? Evaluates a finished experiment's final checkpoints again, clean, on the
same setups with a longer step limit (Meta-World's standard 500), and counts per arm the successes within the
experiment's limit and within the longer one (issue #21, item 2).

An episode ends at success, so one long evaluation answers both: a success within the short limit is a
success whose length is at most that limit. Its short-limit outcomes must equal the experiment's own clean
evaluation (same setups, same actions up to the short limit); the count of episodes where they differ is
reported (`mismatches`, 0 when evaluation is deterministic). Writes RUN/horizon<N>/{eval_info.json,
horizon.json, horizon.md}; the evaluation resumes episode by episode.

    python scripts/horizon.py runs/paper-s0                 # 500 steps
    python scripts/horizon.py runs/paper-s0 --max-steps 300
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from gazereg.evaluation.config import EvalConfig
from gazereg.evaluation.rollout import evaluate
from gazereg.experiment.finished import FinishedRun, read_run
from gazereg.report.ids import RunId
from gazereg.runtime.errors import UsageError, report_errors
from gazereg.runtime.io import atomic_write_json, atomic_write_text


def long_eval_config(run: FinishedRun, max_steps: int) -> tuple[EvalConfig, int]:
    """(the long evaluation of `run`'s final checkpoints, the experiment's own step limit). UsageError when
    `max_steps` is not longer, or `run` is an archive (no checkpoints to roll out)."""
    if max_steps <= run.max_steps:
        raise UsageError(f"--max-steps {max_steps} is not longer than the experiment's {run.max_steps}")
    cfg = run.eval_config(
        run.path / f"horizon{max_steps}", conditions=("clean",), max_steps=max_steps, videos=0
    )
    return cfg, run.max_steps


def tally(long: list[dict[str, Any]], short: list[dict[str, Any]], limit: int) -> dict[str, dict[str, int]]:
    """{arm: {episodes, within_short, within_long, only_long, mismatches}} over training seeds; `short`: the
    experiment's clean records, `limit`: its step limit."""
    key = lambda r: (r["arm"], r["task"], r["seed"])  # noqa: E731
    before = {key(r): bool(r["success"]) for r in short if r["condition"] == "clean"}
    out: dict[str, dict[str, int]] = {}
    for r in long:
        arm = RunId.parse(r["arm"]).arm
        t = out.setdefault(arm, dict(episodes=0, within_short=0, within_long=0, only_long=0, mismatches=0))
        early = bool(r["success"]) and r["length"] <= limit
        t["episodes"] += 1
        t["within_short"] += early
        t["within_long"] += bool(r["success"])
        t["only_long"] += bool(r["success"]) and not early
        t["mismatches"] += before.get(key(r)) is not early
    return out


def markdown(result: dict[str, Any]) -> str:
    short, long = result["short_steps"], result["long_steps"]
    lines = [
        f"## Horizon: {short} vs {long} steps ({result['run']}, clean, final checkpoints)",
        "",
        f"| arm | episodes | success within {short} | success within {long} | only after {short} | "
        f"differs from the experiment's own {short}-step evaluation |",
        "|---|---|---|---|---|---|",
    ]
    for arm, t in result["arms"].items():
        lines.append(
            f"| {arm} | {t['episodes']} | {t['within_short']} | {t['within_long']} | {t['only_long']} | "
            f"{t['mismatches']} |"
        )
    lines += ["", f"Command: `{result['command']}`; wall time {result['wall_s'] / 60:.1f} min.", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="a finished experiment folder (its --out)")
    ap.add_argument("--max-steps", type=int, default=500)
    a = ap.parse_args(argv)
    t0 = time.time()
    run = read_run(a.run)
    cfg, short = long_eval_config(run, a.max_steps)
    long = evaluate(cfg)["episodes"]
    result = {
        "run": str(a.run),
        "short_steps": short,
        "long_steps": a.max_steps,
        "arms": tally(long, run.episodes(), short),
        "command": f"python scripts/horizon.py {a.run} --max-steps {a.max_steps}",
        "wall_s": round(time.time() - t0, 1),
    }
    atomic_write_json(Path(cfg.out) / "horizon.json", result)
    atomic_write_text(Path(cfg.out) / "horizon.md", markdown(result))
    print(markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(report_errors("horizon", main, sys.argv[1:], verbose=False))
