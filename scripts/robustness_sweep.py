"""The perturbation sweep on finished experiments (issue #21 item 7): the final checkpoints of every arm in
the given run folders rolled out again under each lighting and sensor perturbation, on the experiments' own
unseen setups; a condition every folder already evaluated is read from its records, not rolled out again.

    python scripts/robustness_sweep.py runs/paper-abl-a runs/paper-abl-b runs/paper-abl-c runs/paper-abl-d \
        --out runs/robustness

The folders (or their archives, `gazereg archive`, when every condition asked for is in their records) must
share tasks, setups and step limit (else one line naming the difference, exit 2) and name each run once. Reports success per arm and condition (Wilson 95%) and its drop from clean, then, per
condition, each arm minus the baseline and the gaze arm minus each of its controls on the same setups: the
pooled paired difference [95% CI], exact McNemar p, and how many training seeds are above / below 0.
Writes OUT/eval (the new rollouts: a rerun resumes them), OUT/robustness.json and OUT/robustness.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from gazereg.evaluation.config import ROBUSTNESS_CONDITIONS, EvalConfig
from gazereg.evaluation.rollout import evaluate
from gazereg.experiment.finished import read_run
from gazereg.report.build import GAZE_CONTROLS, gaze_and_control
from gazereg.report.comparisons import rate_difference
from gazereg.report.markdown import drop_lines, success_table_lines
from gazereg.report.tables import (
    machine_summary,
    paired_name,
    paired_tests,
    run_of,
    split_paired_name,
    success_table,
    unit_level_tests,
)
from gazereg.runtime.errors import UsageError, report_errors
from gazereg.runtime.io import atomic_write_json, atomic_write_text

SHARED = ("tasks", "episodes", "seed_start", "max_steps", "env")
"""what every run folder must agree on for its episodes to pair with the others'"""


def load_run(run: Path) -> dict[str, Any]:
    """A finished experiment folder or its archive (`gazereg.experiment.read_run`): its evaluation settings
    (SHARED, conditions, workers, batch), final checkpoints {run id: dir, or None in an archive} and own
    evaluation records."""
    finished = read_run(run)
    ev = finished.config["eval"]
    return {
        "tasks": finished.tasks,
        "env": finished.env,
        **{k: ev[k] for k in ("episodes", "seed_start", "max_steps", "conditions", "workers", "batch")},
        "checkpoints": {str(name): path for name, path in finished.checkpoints.items()},
        "records": finished.episodes(),
    }


def plan(runs: dict[Path, dict[str, Any]], conditions: tuple[str, ...]) -> tuple[tuple[str, ...], list[dict]]:
    """(the conditions to roll out, the records to reuse: those of conditions every folder evaluated)."""
    first, info = next(iter(runs.items()))
    seen: dict[str, Path] = {}
    for run, r in runs.items():
        for key in SHARED:
            if r[key] != info[key]:
                raise UsageError(f"{run} has {key} {r[key]!r} but {first} has {info[key]!r}")
        for name in r["checkpoints"]:
            if name in seen:
                raise UsageError(f"run {name} is in both {seen[name]} and {run}")
            seen[name] = run
    shared = set.intersection(*(set(r["conditions"]) for r in runs.values()))
    reused = [e for r in runs.values() for e in r["records"] if e["condition"] in shared & set(conditions)]
    return tuple(c for c in conditions if c not in shared), reused


def comparisons(records: list[dict[str, Any]]) -> tuple[dict[str, dict], dict[str, dict]]:
    """(pooled paired tests, seed-level tests): each arm against the baseline, and the gaze arm against each
    of its controls present, per condition."""
    paired, seeds = paired_tests(records), unit_level_tests(records, "seed")
    arms = tuple({run_of(e).arm for e in records})
    for control in GAZE_CONTROLS:
        pair = gaze_and_control(records, arms, control)
        if not pair:
            continue
        paired.update(paired_tests(pair, control))
        seeds.update(unit_level_tests(pair, "seed", control))
    return paired, seeds


def difference_lines(result: dict[str, Any]) -> list[str]:
    """One row per condition, one column per comparison: `diff [CI], p, seeds above/below 0`."""
    conds, paired, seeds = result["conditions"], result["paired"], result["seed_level"]
    pairs = list(dict.fromkeys(split_paired_name(k)[:2] for k in paired))  # (arm, reference)
    header = " | ".join(f"{a} vs {b}" for a, b in pairs)
    lines = [f"| condition | {header} |", "|---|" + "---|" * len(pairs)]
    for c in conds:
        cells = []
        for a, b in pairs:
            t, s = paired.get(paired_name(a, b, c)), seeds.get(paired_name(a, b, c))
            if t is None:
                cells.append("-")
                continue
            above = f", seeds {s['above']}/{s['below']}" if s else ""
            cells.append(f"{rate_difference(t)}, p {t['mcnemar_p']:.2g}{above}")
        lines.append(f"| {c} | " + " | ".join(cells) + " |")
    return lines


def markdown(result: dict[str, Any]) -> str:
    """robustness.md: what ran, success and drop tables, the paired differences."""
    rolled = ", ".join(result["rolled_out"]) or "none"
    return "\n".join(
        [
            f"## Perturbation sweep: final checkpoints of {', '.join(result['runs'])}",
            "",
            f"Tasks {', '.join(result['tasks'])}; {result['episodes']} unseen setups per task and condition "
            f"(seeds {result['seed_start']}..{result['seed_start'] + result['episodes'] - 1}), every run "
            f"on the same ones. Rolled out here: {rolled}; the other conditions are the experiments' own "
            "records.",
            "",
            "Success (pooled over tasks and training seeds; Wilson 95% intervals):",
            "",
            *success_table_lines(result),
            "",
            *drop_lines(result),
            "",
            "A minus B on the same setups (pooled paired difference [95% CI], exact McNemar p, training "
            "seeds above / below 0):",
            "",
            *difference_lines(result),
            "",
            f"Command: `{result['command']}`; {result['machine']['summary']}; wall time "
            f"{result['wall_s'] / 60:.1f} min.",
            "",
        ]
    )


def ordered_success(records: list[dict[str, Any]], conditions: tuple[str, ...]) -> dict[str, dict]:
    """success_table with the baseline first, then the arms by name, and the conditions in sweep order."""
    table = success_table(records)
    arms = sorted(table, key=lambda a: (a != "baseline", a))
    return {a: {c: table[a][c] for c in conditions if c in table[a]} for a in arms}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", type=Path, nargs="+", help="finished experiment folders (their --out)")
    p.add_argument("--conditions", nargs="+", default=list(ROBUSTNESS_CONDITIONS))
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(sys.argv[1:] if argv is None else argv)
    started = time.perf_counter()
    conditions = tuple(args.conditions)
    if "clean" not in conditions:
        raise UsageError("--conditions must include clean (the drop from clean needs it)")
    runs = {run: load_run(run) for run in args.runs}
    rollout, records = plan(runs, conditions)
    info = next(iter(runs.values()))
    archives = [str(run) for run, r in runs.items() if None in r["checkpoints"].values()]
    if rollout and archives:
        raise UsageError(
            f"{', '.join(rollout)} must be rolled out, but {', '.join(archives)} keep no checkpoints (archives): "
            "give the run folders, or only conditions every folder evaluated"
        )
    if rollout:
        cfg = EvalConfig(
            checkpoints=tuple(f"{n}={d}" for r in runs.values() for n, d in r["checkpoints"].items()),
            **{
                k: info[k]
                for k in ("tasks", "episodes", "seed_start", "max_steps", "workers", "batch", "env")
            },
            conditions=rollout,
            videos=0,
            out=args.out / "eval",
        )
        records += evaluate(cfg)["episodes"]
    paired, seeds = comparisons(records)
    result = {
        "runs": [str(r) for r in args.runs],
        **{k: info[k] for k in ("tasks", "episodes", "seed_start")},
        "conditions": list(conditions),
        "rolled_out": list(rollout),
        "success": ordered_success(records, conditions),
        "paired": paired,
        "seed_level": seeds,
        "machine": machine_summary(),
        "command": " ".join(
            ["python scripts/robustness_sweep.py", *(sys.argv[1:] if argv is None else argv)]
        ),
        "wall_s": round(time.perf_counter() - started, 1),
    }
    atomic_write_json(args.out / "robustness.json", result)
    text = markdown(result)
    atomic_write_text(args.out / "robustness.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(report_errors("robustness_sweep", main, sys.argv[1:], verbose=False))
