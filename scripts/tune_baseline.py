"""Tune the reference VLA's recipe WITHOUT gaze, on validation setups that are neither training nor evaluation
setups (issue #21, step 1: a strong baseline first, gaze blind).

    .venv/bin/python scripts/tune_baseline.py                      # every candidate not yet done, in order
    .venv/bin/python scripts/tune_baseline.py --only default ema   # some of them
    .venv/bin/python scripts/tune_baseline.py --table              # only rewrite docs/tuning/baseline.md

Protocol (fixed before any result was seen):
- Data: the `quick` preset's demonstrations (reach-v3 and button-press-topdown-v3, 50 per task on setups 0..49
  plus replacements of the expert's failures), the same for every candidate.
- Validation: 25 setups per task from seed 1300 (Meta-World seeds 1300..1324), clean. Training uses seeds
  0..69 at most and the evaluation presets 1000..1049 (GLC 1700..; this run's alignment episodes 1800..):
  disjoint.
- Budget: the `paper` preset's 8,000 steps of batch 32, two training seeds (0, 1) per candidate, the baseline
  arm only (no gaze term anywhere).
- Candidates change one thing against `default` (today's recipe), in the order below, which is the order of
  how much each was expected to matter; a candidate is one `gazereg experiment` run folder, resumable.
- Choice: the candidate with the most validation successes over both seeds and tasks. The gaze arm then uses
  the chosen recipe unchanged, tuning at most the gaze weight and layers on the same validation setups.
- Round 2 (`--round 2`, stated on 2026-11-24 with 4 of the 8 one-factor results known and before the other 4):
  once every one-factor candidate has run, `combined` applies together every change whose candidate had more
  validation successes than `default`, in the order above, on the same budget and setups (none when fewer
  than two qualify). The choice is then the best of all candidates, `combined` included.
Each finished candidate writes docs/tuning/baseline/<name>.json (its command, wall time and validation
successes per task and seed); docs/tuning/baseline.md is the table of every finished candidate.
"""

from __future__ import annotations

import argparse
import json
import shlex
import time
from pathlib import Path
from typing import Any

from gazereg.experiment.finished import FinishedRun, read_run
from gazereg.experiment.tuning import (
    candidate_record,
    choose,
    experiment_command,
    markdown_table,
    per_seed_text,
    per_task_text,
    run_experiment,
    totals,
    write_record,
)
from gazereg.runtime.io import atomic_write_text

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "tuning"
BASE = [
    "--preset", "quick", "--arms", "baseline", "--train-seeds", "0", "1", "--train.steps", "8000",
    "--eval.seed-start", "1300", "--eval.episodes", "25", "--convergence-points", "1", "--heldout-per-task", "1",
    "--eval.batch", "1",  # episode by episode, as the first candidates ran (before lockstep evaluation)
]  # fmt: skip
CANDIDATES: dict[str, tuple[str, list[str]]] = {
    "default": ("today's recipe: 96 px, width 128, depth 4, chunk 4, lr 1e-3, shift 4, no EMA", []),
    "ema": ("EMA of the weights, decay 0.999", ["--train.optim.ema-decay", "0.999"]),
    "lr5e-4": ("learning rate 5e-4", ["--train.optim.lr", "5e-4"]),
    "chunk8": ("action chunks of 8", ["--train.policy.chunk", "8"]),
    "wide": ("width 192, depth 6", ["--train.policy.dim", "192", "--train.policy.depth", "6"]),
    "shift8": ("random shift of 8 px", ["--train.shift", "8"]),
    "steps16k": ("16,000 steps", ["--train.steps", "16000"]),
    "px128": ("128 px images, 16 px patches", ["--image-size", "128", "--train.policy.image-hw", "128", "128",
                                                "--train.policy.patch-size", "16"]),
}  # fmt: skip


def result_path(name: str) -> Path:
    return DOCS / "baseline" / f"{name}.json"


def successes(name: str) -> int:
    """Validation successes of a finished candidate, over both seeds and tasks."""
    return totals(json.loads(result_path(name).read_text())["validation"])[0]


def combined() -> tuple[str, list[str]] | None:
    """Round 2's candidate (module docstring): (change, overrides), or None when fewer than two one-factor
    changes beat `default`. SystemExit naming the one-factor candidates not yet run."""
    missing = [name for name in CANDIDATES if not result_path(name).exists()]
    if missing:
        raise SystemExit(f"round 2 needs every one-factor candidate; not run yet: {', '.join(missing)}")
    winners = [n for n in CANDIDATES if n != "default" and successes(n) > successes("default")]
    if len(winners) < 2:
        return None
    return "round 2: " + " + ".join(winners), [arg for n in winners for arg in CANDIDATES[n][1]]


def chosen() -> str | None:
    """The recipe's candidate once tuning is over (round 1 complete, and `combined` run where round 2 has
    one): the most validation successes, ties to the earlier candidate (round 1's order, `combined` last);
    None while tuning goes on."""
    if any(not result_path(n).exists() for n in CANDIDATES):
        return None
    if combined() is not None and not result_path("combined").exists():
        return None
    return choose({n: successes(n) for n in all_candidates() if result_path(n).exists()})


def all_candidates() -> dict[str, tuple[str, list[str]]]:
    """Every candidate whose definition is known now: round 1's, and `combined` once round 2 has run or can."""
    out = dict(CANDIDATES)
    if result_path("combined").exists():
        r = json.loads(result_path("combined").read_text())
        out["combined"] = (r["change"], r["overrides"])
    return out


def command(name: str, overrides: list[str] | None = None) -> list[str]:
    """The `gazereg experiment` command line of candidate `name` (its overrides after the shared ones)."""
    extra = CANDIDATES[name][1] if overrides is None else overrides
    return experiment_command(BASE, extra, f"runs/tune/{name}")


def candidate_result(run: FinishedRun, name: str, change: str, overrides: list[str]) -> dict[str, Any]:
    """Candidate `name`'s record (docs/tuning/baseline/<name>.json, less this call's wall time) from its
    finished experiment `run` (a run folder or its archive): its command, stage times, machine, date and
    validation successes per task and training seed."""
    return candidate_record(run, name, change, overrides, command(name, overrides))


def run_candidate(name: str, change: str, overrides: list[str]) -> Path:
    """Run (or resume) candidate `name`; write and return docs/tuning/baseline/<name>.json."""
    t0 = time.time()
    run_experiment(command(name, overrides), ROOT)
    result = candidate_result(read_run(ROOT / "runs" / "tune" / name), name, change, overrides)
    result["wall_s_this_call"] = round(time.time() - t0, 1)
    path = result_path(name)
    write_record(path, result)
    return path


def table() -> str:
    """docs/tuning/baseline.md: every finished candidate's validation successes, best first."""
    rows = []
    for name in all_candidates():
        if not result_path(name).exists():
            continue
        r = json.loads(result_path(name).read_text())
        val = r["validation"]
        total, n = totals(val)
        rows.append((total, n, name, r["change"], per_task_text(val), per_seed_text(val)))
    rows.sort(key=lambda row: -row[0] / max(row[1], 1))
    lines = [
        "# Baseline tuning on validation setups (no gaze)",
        "",
        "Written by `python scripts/tune_baseline.py` (its docstring states the protocol); each row is one",
        "candidate's `gazereg experiment` run, its command in docs/tuning/baseline/<candidate>.json.",
        "",
    ]
    lines += markdown_table(
        ("candidate", "change", "validation success", "per task", "per training seed"),
        [(name, change, f"{k}/{n} = {k / n:.2f}", pt, ps) for k, n, name, change, pt, ps in rows],
    )
    done = {row[2] for row in rows}
    todo = [name for name in CANDIDATES if name not in done]
    lines += ["", f"Not run yet: {', '.join(todo)}." if todo else "Every one-factor candidate has run."]
    choice = chosen()
    if choice is not None:
        overrides = shlex.join(all_candidates()[choice][1]) or "no override"
        lines += [
            "",
            f"**Chosen recipe: {choice}** (the most validation successes; `{overrides}` on the shared command). The",
            "`paper` and `sweep` presets train with it (`gazereg.training.config.tuned`).",
        ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", nargs="+", choices=list(CANDIDATES), help="run these candidates (default: all)")
    p.add_argument("--table", action="store_true", help="only rewrite docs/tuning/baseline.md")
    p.add_argument(
        "--round", type=int, choices=(1, 2), default=1, help="2: the combined candidate (docstring)"
    )
    a = p.parse_args(argv)
    todo: dict[str, tuple[str, list[str]]] = {}
    if a.round == 2 and not a.table:
        c = combined()
        if c is None:
            print(
                "round 2: fewer than two one-factor changes beat default; the best single candidate is the choice"
            )
        else:
            todo["combined"] = c
    elif not a.table:
        todo = {n: CANDIDATES[n] for n in a.only or CANDIDATES if a.only or not result_path(n).exists()}
    for name, (change, overrides) in todo.items():
        print(f"candidate {name}: {shlex.join(command(name, overrides))}", flush=True)
        run_candidate(name, change, overrides)
        atomic_write_text(DOCS / "baseline.md", table())
    DOCS.mkdir(parents=True, exist_ok=True)
    atomic_write_text(DOCS / "baseline.md", table())
    print(table())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
