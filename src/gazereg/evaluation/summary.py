"""Summaries of an evaluation's episodes: success rates with Wilson intervals, drops, paired tests, a table.

summary = summarize(records)      # records: eval_info.json's "episodes"
print(format_table(summary))
"""

from __future__ import annotations

from collections import defaultdict
from typing import Any

import numpy as np

from gazereg.evaluation.stats import mcnemar_exact, wilson


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Per arm, condition and task: successes, n, rate, Wilson 95% interval, mean length; pooled over tasks;
    each condition's drop from clean (on the condition's setups); paired exact tests between arms on the shared seeds."""
    by: dict[tuple[str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in records:
        by[(r["arm"], r["condition"], r["task"])].append(r)

    def cell(rs: list[dict[str, Any]]) -> dict[str, Any]:
        k, n = sum(r["success"] for r in rs), len(rs)
        lo, hi = wilson(k, n)
        out = {
            "successes": k,
            "n": n,
            "rate": k / n if n else float("nan"),
            "ci95": [lo, hi],
            "mean_length": float(np.mean([r["length"] for r in rs])) if rs else float("nan"),
        }
        dist = [r["min_distance"] for r in rs if "min_distance" in r]
        if dist:
            out["mean_min_distance"] = float(np.mean(dist))
        return out

    arms = sorted({r["arm"] for r in records})
    conditions = list(dict.fromkeys(r["condition"] for r in records))
    tasks = list(dict.fromkeys(r["task"] for r in records))
    out: dict[str, Any] = {"arms": {}, "paired": {}}
    for arm in arms:
        out["arms"][arm] = {}
        for cond in conditions:
            rs = [r for t in tasks for r in by[(arm, cond, t)]]
            entry = {"pooled": cell(rs), "tasks": {t: cell(by[(arm, cond, t)]) for t in tasks}}
            out["arms"][arm][cond] = entry
        if "clean" in out["arms"][arm]:
            clean = {(r["task"], r["seed"]): bool(r["success"]) for t in tasks for r in by[(arm, "clean", t)]}
            for cond in conditions:
                # the clean rate on this condition's setups (fewer than clean's with robustness_episodes)
                keys = [(r["task"], r["seed"]) for t in tasks for r in by[(arm, cond, t)]]
                same = [clean[k] for k in keys if k in clean]
                rate = sum(same) / len(same) if same else float("nan")
                out["arms"][arm][cond]["drop_from_clean"] = rate - out["arms"][arm][cond]["pooled"]["rate"]

    def outcomes(arm: str, cond: str) -> list[bool]:
        rs = sorted((r for t in tasks for r in by[(arm, cond, t)]), key=lambda r: (r["task"], r["seed"]))
        return [bool(r["success"]) for r in rs]

    for i, a in enumerate(arms):
        for b in arms[i + 1 :]:
            for cond in conditions:
                out["paired"][f"{a} vs {b} | {cond}"] = mcnemar_exact(outcomes(a, cond), outcomes(b, cond))
    return out


def format_table(summary: dict[str, Any]) -> str:
    """A markdown table: one row per arm, one column per condition (pooled success, 95% interval)."""
    arms = list(summary["arms"])
    conditions = list(next(iter(summary["arms"].values())))
    lines = ["| arm | " + " | ".join(conditions) + " |", "|---|" + "---|" * len(conditions)]
    for arm in arms:
        cells = []
        for c in conditions:
            p = summary["arms"][arm][c]["pooled"]
            cells.append(
                f"{p['successes']}/{p['n']} = {p['rate']:.2f} [{p['ci95'][0]:.2f}, {p['ci95'][1]:.2f}]"
            )
        lines.append(f"| {arm} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
