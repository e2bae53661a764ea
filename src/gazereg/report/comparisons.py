"""The paired comparisons of report.json as markdown tables: each arm against its reference on the same
setups (`paired_lines`) and within each task (`per_task_paired_lines`), the same comparisons with the training
seed or the task as the unit (`unit_level_lines`), and the one row-per-comparison table writer they and the
closest-approach tables share (`comparison_lines`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from gazereg.report.tables import split_paired_name


def rate_difference(test: dict[str, Any]) -> str:
    """A paired test's success-rate difference and its 95% interval, e.g. `+0.12 [+0.05, +0.19]`; `n/a` for
    reports written before it was computed."""
    if "rate_diff" not in test:
        return "n/a"
    lo, hi = test["rate_ci95"]
    return f"{test['rate_diff']:+.2f} [{lo:+.2f}, {hi:+.2f}]"


def comparison_lines(
    comparisons: dict[str, dict[str, Any]],
    columns: list[str],
    cells: Callable[[str, str, dict], list[str]],
    label: str = "comparison (A vs B)",
) -> list[str]:
    """A table with one row per comparison ("A vs B | condition" keys, `tables.paired_name`): its two leading
    columns (`label`, condition), then `columns` filled by `cells(A, B, the comparison's values)`."""
    lines = [
        f"| {label} | condition | " + " | ".join(columns) + " |",
        "|---|---|" + "---|" * len(columns),
    ]
    for k, v in comparisons.items():
        a, b, condition = split_paired_name(k)
        lines.append(f"| {a} vs {b} | {condition} | " + " | ".join(cells(a, b, v)) + " |")
    return lines


def paired_lines(report: dict[str, Any]) -> list[str]:
    """Each arm against the baseline on the same setups: the paired success difference with its interval,
    exact McNemar and Fisher p-values; then the same within each task where the report has them
    (`per_task_paired_lines`)."""
    if not report.get("paired"):
        return []
    columns = ["pairs", "only A solved", "only B solved", "success A - B [95% CI]", "McNemar p", "Fisher p"]
    return [
        "",
        "## Paired comparisons (same setups; exact McNemar on discordant episodes, Fisher on counts)",
        "",
        *comparison_lines(
            report["paired"],
            columns,
            lambda a, b, v: [
                str(v["pairs"]),
                str(v[f"{a}_only"]),
                str(v[f"{b}_only"]),
                rate_difference(v),
                f"{v['mcnemar_p']:.3f}",
                f"{v['fisher_p']:.3f}",
            ],
        ),
        *per_task_paired_lines(report),
    ]


def per_task_paired_lines(report: dict[str, Any]) -> list[str]:
    """The paired comparisons within each task (`tables.per_task_paired_tests`): one row per comparison,
    condition and task, with the McNemar p and its Holm adjustment over the comparison's tasks."""
    if not report.get("paired_per_task"):
        return []
    lines = [
        "",
        "## Paired comparisons per task (exact McNemar; Holm: adjusted over the comparison's tasks)",
        "",
        "| comparison (A vs B) | condition | task | pairs | only A solved | only B solved "
        "| success A - B [95% CI] | McNemar p | Holm p |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, tests in report["paired_per_task"].items():
        a, b, condition = split_paired_name(name)
        for task, v in tests.items():
            lines.append(
                f"| {a} vs {b} | {condition} | {task} | {v['pairs']} | {v[f'{a}_only']} | {v[f'{b}_only']} "
                f"| {rate_difference(v)} | {v['mcnemar_p']:.3f} | {v['holm_p']:.3f} |"
            )
    return lines


def unit_level_table(
    comparisons: dict[str, dict[str, Any]], unit: str = "seed", digits: int = 2
) -> list[str]:
    """`tables.unit_level_tests` results (the `unit`, "seed" or "task", as the sample) as a table; differences
    with `digits` decimals."""
    f = f"+.{digits}f"
    return comparison_lines(
        comparisons,
        [
            f"A - B per {unit}",
            "mean [95% CI]",
            f"{unit}s above / below 0",
            "sign-flip p",
            "smallest possible p",
        ],
        lambda a, b, v: [
            ", ".join(format(d, f) for d in v["diffs"]),
            f"{v['mean_diff']:{f}} [{v['ci95'][0]:{f}}, {v['ci95'][1]:{f}}]",
            f"{v['above']} / {v['below']}",
            f"{v['sign_flip_p']:.2f}",
            f"{v['p_floor']:.2f}",
        ],
    )


UNIT_HEADINGS = {
    "seed": "## Seed level (the training seed is the unit: per-seed paired differences, Student-t 95% interval)",
    "task": "## Task level (the task is the unit: per-task paired differences, Student-t 95% interval)",
}


def unit_level_lines(report: dict[str, Any]) -> list[str]:
    """The paired success comparisons again with the training seed, then the task, as the unit
    (`tables.unit_level_tests`), each where the report has them."""
    lines = []
    for unit, heading in UNIT_HEADINGS.items():
        if report.get(f"{unit}_level"):
            lines += ["", heading, ""]
            if unit == "task":  # the order of each row's per-task differences
                order = next(iter(report["task_level"].values()))["units"]
                lines += [f"Per-task differences in the order {', '.join(order)}.", ""]
            lines += unit_level_table(report[f"{unit}_level"], unit)
    return lines
