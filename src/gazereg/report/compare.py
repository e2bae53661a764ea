"""Two experiment runs side by side, from their records: the same arms, evaluated on the same setups, after
different training (a longer budget, another gaze weight, other layers ...).

The question it answers is "did the change move success?", e.g. whether training longer still raises it.
Episodes pair by (arm, training seed, task, condition, setup seed), so each arm gets an exact McNemar test of
run B against run A on the setups both evaluated, and a paired difference of the closest approach (metres)
where the simulator records one. The command, which reads the two run folders (or their archives), is
`gazereg.experiment.compare`:

    gazereg compare runs/paper runs/paper6k [--out runs/paper6k/compare.md]
"""

from __future__ import annotations

from typing import Any

from gazereg.report.comparisons import rate_difference
from gazereg.report.ids import RunId
from gazereg.report.tables import paired_distance_tests, paired_tests, run_of, success_table
from gazereg.runtime.config import config_diff


def _relabel(records: list[dict[str, Any]], arm: str, label: str) -> list[dict[str, Any]]:
    """One arm's records with the arm renamed to `label`, keeping the training seed."""
    out = []
    for r in records:
        run = run_of(r)
        if run.arm == arm:
            out.append({**r, "arm": str(RunId(label, run.seed, run.step))})
    return out


def _arms(records: list[dict[str, Any]]) -> set[str]:
    return {run_of(r).arm for r in records}


def compare_records(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """{"arm | condition": {a, b (success cells), pairs, b_only, a_only, rate_diff, rate_ci95, mcnemar_p, fisher_p,
    distance}} for every arm and condition both runs evaluated. `a_only`/`b_only` count the paired setups only
    that run solved; `rate_diff` is B's success rate minus A's on the paired setups, `rate_ci95` its 95%
    interval; `distance` is the paired closest-approach difference B - A (negative: B came closer), or None."""
    shared_arms = sorted(_arms(a) & _arms(b))
    out: dict[str, dict[str, Any]] = {}
    for arm in shared_arms:
        # Run A and run B as two arms of one experiment: the paired tests of B against reference A.
        records = _relabel(a, arm, "A") + _relabel(b, arm, "B")
        cells = success_table(records)
        distances = paired_distance_tests(records, reference="A")
        for name, test in paired_tests(records, reference="A").items():
            cond = name.split(" | ", 1)[1]
            out[f"{arm} | {cond}"] = {
                "a": {k: cells["A"][cond][k] for k in ("successes", "n", "rate", "ci95")},
                "b": {k: cells["B"][cond][k] for k in ("successes", "n", "rate", "ci95")},
                "pairs": test["pairs"],
                "b_only": test["B_only"],
                "a_only": test["A_only"],
                "rate_diff": test["rate_diff"],
                "rate_ci95": test["rate_ci95"],
                "mcnemar_p": test["mcnemar_p"],
                "fisher_p": test["fisher_p"],
                "distance": distances.get(name),
            }
    if not out:
        raise ValueError(
            "the two runs share no evaluated episode (same arm, training seed, task, condition and setup seed); "
            f"A has arms {sorted(_arms(a))} on setups {_seed_span(a)}, "
            f"B has arms {sorted(_arms(b))} on setups {_seed_span(b)}"
        )
    return out


def _seed_span(records: list[dict[str, Any]]) -> str:
    seeds = sorted({int(r["seed"]) for r in records})
    return f"{seeds[0]}..{seeds[-1]}" if seeds else "none"


def success_curves(report: dict[str, Any] | None) -> dict[str, dict[str, list[Any]]]:
    """{arm: {steps, rates}}: a run's clean success at its training checkpoints, from its report.json's
    content (empty when the run has no report yet: None)."""
    arms = (report or {}).get("convergence", {}).get("arms", {})
    return {arm: {"steps": c["steps"], "rates": c["rates"]} for arm, c in arms.items()}


def compare_tasks(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, Any]]]:
    """{task: `compare_records` of that task's episodes} for every task both runs evaluated with a shared
    episode, in the order of A's records; empty when they share at most one task (the pooled rows are then
    the task's)."""
    tasks = [t for t in dict.fromkeys(r["task"] for r in a) if any(r["task"] == t for r in b)]
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for task in tasks:
        try:
            out[task] = compare_records(
                [r for r in a if r["task"] == task], [r for r in b if r["task"] == task]
            )
        except ValueError:  # this task's episodes share no setup: nothing to pair
            continue
    return out if len(out) > 1 else {}


def comparison(
    names: tuple[str, str],
    configs: tuple[dict[str, Any], dict[str, Any]],
    records: tuple[list[dict[str, Any]], list[dict[str, Any]]],
    reports: tuple[dict[str, Any] | None, dict[str, Any] | None],
) -> dict[str, Any]:
    """Runs A and B compared (each given as its name, saved config, evaluation records and report or None):
    their config differences, the per-arm, per-condition paired comparison of B against A (`rows`, every
    task pooled; `tasks`, each task's own when they share several: `compare_tasks`), each run's
    success-versus-steps curve, and each task's instruction as the reports state it (B's where both do)."""
    return {
        "a": names[0],
        "b": names[1],
        "differences": config_diff(configs[0], configs[1], ignore=("out",)),
        "rows": compare_records(*records),
        "tasks": compare_tasks(*records),
        "curves": {"a": success_curves(reports[0]), "b": success_curves(reports[1])},
        "instructions": {
            k: v
            for r in reversed(reports)
            if r
            for k, v in r.get("demos", {}).get("instructions", {}).items()
        },
    }


def _pct(cell: dict[str, Any]) -> str:
    lo, hi = cell["ci95"]
    return f"{cell['successes']}/{cell['n']} = {cell['rate']:.2f} [{lo:.2f}, {hi:.2f}]"


def compare_markdown(result: dict[str, Any], level: int = 2) -> str:
    """The comparison as a markdown section (heading `level`): what differs, then one row per arm and
    condition, then each run's success-versus-steps curve."""
    diffs = result["differences"]
    lines = [
        f"{'#' * level} {result['b']} (B) against {result['a']} (A)",
        "",
        "What differs: "
        + (", ".join(f"`{k}` {v[0]!r} -> {v[1]!r}" for k, v in diffs.items()) if diffs else "nothing"),
        "",
        "| arm | condition | A success [95% CI] | B success [95% CI] | paired setups | only A / only B "
        "| success B - A [95% CI] | McNemar p | closest approach B - A (m) [95% CI] |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, row in result["rows"].items():
        arm, cond = name.split(" | ", 1)
        d = row["distance"]
        dist = f"{d['mean_diff']:+.3f} [{d['ci95'][0]:+.3f}, {d['ci95'][1]:+.3f}]" if d else "n/a"
        lines.append(
            f"| {arm} | {cond} | {_pct(row['a'])} | {_pct(row['b'])} | {row['pairs']} "
            f"| {row['a_only']} / {row['b_only']} | {rate_difference(row)} | {row['mcnemar_p']:.3g} | {dist} |"
        )
    tasks = result.get("tasks", {})
    if tasks:
        lines += [
            "",
            "Per task:",
            "",
            "| task | arm | condition | A success [95% CI] | B success [95% CI] | only A / only B | McNemar p |",
            "| --- | --- | --- | --- | --- | --- | --- |",
        ]
        said = result.get("instructions", {})
        for task, rows in tasks.items():
            label = f"{task}: {said[task]}" if said.get(task) else task
            for name, row in rows.items():
                arm, cond = name.split(" | ", 1)
                lines.append(
                    f"| {label} | {arm} | {cond} | {_pct(row['a'])} | {_pct(row['b'])} "
                    f"| {row['a_only']} / {row['b_only']} | {row['mcnemar_p']:.3g} |"
                )
    curves = result.get("curves", {})
    if any(curves.values()):
        lines += ["", "Clean success at each run's own checkpoints (its convergence episodes):", ""]
        for key in ("a", "b"):
            for arm, c in curves.get(key, {}).items():
                points = ", ".join(f"{s}: {r:.2f}" for s, r in zip(c["steps"], c["rates"]))
                lines.append(f"- {key.upper()} {arm}: {points}")
    lines += [
        "",
        "Pairs are the same training seed, task, condition and setup seed in both runs; McNemar is exact "
        "(two-sided) on the discordant pairs.",
    ]
    return "\n".join(lines) + "\n"
