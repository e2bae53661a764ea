"""The experiment's report as markdown text, rendered from report.json (a dict); nothing here writes files.

- `markdown(report)`: the whole report.md of one run.
- `results_block(report, figure)`: the shorter block that scripts/update_results.py puts into docs/results.md;
  its head, `headline_lines(report)` (the run line and the success table), is the README's headline.

Every `*_lines` function returns markdown lines (no trailing newlines) for one section, or [] when the report
lacks that section's data.
"""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Any

from gazereg.report.blockdata import BlockData
from gazereg.report.comparisons import paired_lines, unit_level_lines
from gazereg.report.ids import RunId
from gazereg.report.progress import measure_lines
from gazereg.report.sections import glc_lines, header_lines, numerics_text

# attention-vs-gaze metrics shown, in this column order: report.md shows them all, the results block a subset
REPORT_ALIGNMENT_KEYS = (
    "gaze_kl",
    "gaze_cc",
    "gaze_sim",
    "gaze_nss",
    "gaze_auc_judd",
    "object_mass",
    "object_mass_chance",
)
BLOCK_ALIGNMENT_KEYS = ("gaze_kl", "gaze_cc", "gaze_auc_judd", "object_mass", "object_mass_chance")


def fmt_cell(c: dict[str, Any]) -> str:
    """One success cell, `successes/n = rate [lo, hi]` (Wilson 95%), from a success-table entry."""
    return f"{c['successes']}/{c['n']} = {c['rate']:.2f} [{c['ci95'][0]:.2f}, {c['ci95'][1]:.2f}]"


def per_task_lines(report: dict[str, Any], condition: str = "clean") -> list[str]:
    """Successes per task under `condition` (pooled over training seeds), Wilson 95%: one row per arm, or with
    more tasks than arms or when the report knows each task's instruction one row per task (with its
    instruction and its demonstrations when the report has them)."""
    t, tasks = report["success"], report["tasks"]
    said = report.get("demos", {}).get("instructions")

    def cell(arm: str, task: str) -> str:
        c = t[arm][condition]["per_task"][task]
        return f"{c['successes']}/{c['n']} [{c['ci95'][0]:.2f}, {c['ci95'][1]:.2f}]"

    if len(tasks) <= len(t) and not said:
        return [
            f"Per task ({condition}):",
            "",
            "| arm | " + " | ".join(tasks) + " |",
            "|---|" + "---|" * len(tasks),
            *[f"| {a} | " + " | ".join(cell(a, k) for k in tasks) + " |" for a in t],
        ]
    demos = report.get("demos", {}).get("per_task")
    head = ["task", *(["instruction"] if said else []), *(["demos"] if demos else []), *t]
    return [
        f"Per task ({condition}):",
        "",
        "| " + " | ".join(head) + " |",
        "|---|" + "---|" * (len(head) - 1),
        *[
            f"| {k} | "
            + (f"{said.get(k, '')} | " if said else "")
            + "".join(f"{demos.get(k, 0)} | " if demos else "")
            + " | ".join(cell(a, k) for a in t)
            + " |"
            for k in tasks
        ],
    ]


def per_seed_lines(report: dict[str, Any]) -> list[str]:
    """Successes per training seed (pooled over tasks), one row per run."""
    runs = report.get("per_seed")
    if not runs:
        return []
    conds = list(next(iter(runs.values())))
    lines = [
        "",
        "Per training seed (successes over tasks):",
        "",
        "| run | " + " | ".join(conds) + " |",
        "|---|" + "---|" * len(conds),
    ]
    for run, row in runs.items():
        lines.append(
            f"| {run} | " + " | ".join(f"{row[c][0]}/{row[c][1]}" if c in row else "-" for c in conds) + " |"
        )
    return lines


def val_loss_lines(report: dict[str, Any]) -> list[str]:
    """Each arm's final action loss on its run's validation episodes (demonstrations held out of training, on
    training setups; a run's seed fixes the split, so arms with the same seed share it)."""
    runs = {k: v for k, v in (report.get("val_loss") or {}).items() if v is not None}
    if not runs:
        return []
    by_arm: dict[str, dict[int, float]] = {}
    for name, v in runs.items():
        run = RunId.parse(name)
        by_arm.setdefault(run.arm, {})[run.seed] = v
    seeds = sorted({s for d in by_arm.values() for s in d})
    lines = [
        "",
        "## Action loss on held-out demonstrations (end of training; lower is better)",
        "",
        "| arm | " + " | ".join(f"s{s}" for s in seeds) + " | mean |",
        "|---|" + "---|" * (len(seeds) + 1),
    ]
    for arm, d in by_arm.items():
        cells = [f"{d[s]:.4f}" if s in d else "-" for s in seeds]
        lines.append(f"| {arm} | " + " | ".join(cells) + f" | {sum(d.values()) / len(d):.4f} |")
    return lines


def _steps(n: int | None) -> str:
    return "not reached" if n is None else str(n)


def _reach_cell(c: dict[str, Any]) -> str:
    """A bootstrapped first crossing, `steps [lo, hi]`, each "not reached" where no checkpoint reaches it."""
    lo, hi = c["ci95"]
    return f"{_steps(c['steps'])} [{_steps(lo)}, {_steps(hi)}]"


def _difference_cell(c: dict[str, Any]) -> str:
    """An arm's crossing minus the baseline's, `+d [lo, hi]` steps; "-" unless both reach it in the sample."""
    d = c.get("minus_reference")
    if d is None or d["steps"] is None or d["ci95"] is None:
        return "-"
    return f"{d['steps']:+d} [{d['ci95'][0]:+d}, {d['ci95'][1]:+d}]"


def bootstrap_lines(conv: dict[str, Any]) -> list[str]:
    """The steps to the baseline's final success and to the threshold with their paired bootstrap intervals,
    one row per arm; nothing for a report made before the convergence carried them."""
    boot = conv.get("bootstrap")
    if not boot:
        return []
    final, threshold = boot["to_baseline_final"], boot["to_threshold"]
    head = ["arm"]
    if final is not None:
        head += [f"steps to baseline's final ({conv['baseline_final']:.2f})", "reached", "minus baseline's"]
    head += [f"steps to {conv['threshold']:.2f}", "reached"]
    rows = []
    for arm, t in threshold.items():
        cells = [arm]
        if final is not None:
            cells += [_reach_cell(final[arm]), f"{final[arm]['reached']:.2f}", _difference_cell(final[arm])]
        rows.append("| " + " | ".join([*cells, _reach_cell(t), f"{t['reached']:.2f}"]) + " |")
    tail = "; minus baseline's: the arm's steps minus the baseline's, over the resamples in which both do"
    return [
        f"Steps to reach a success rate, with a paired bootstrap: the {boot['units']} evaluation units "
        f"{boot['unit']}, which every arm and checkpoint evaluate, drawn with replacement {boot['resamples']} "
        f"times (seed {boot['seed']}), each draw applied to every arm and checkpoint alike (and to the "
        "baseline's final rate). A cell is the first checkpoint at or above the rate [2.5th, 97.5th percentile "
        'over the resamples]; "not reached": no checkpoint up to the arm\'s last reaches it. Reached: the share '
        f"of resamples in which it does{tail if final is not None else ''}.",
        "",
        "| " + " | ".join(head) + " |",
        "|---|" + "---|" * (len(head) - 1),
        *rows,
        "",
    ]


def convergence_lines(report: dict[str, Any]) -> list[str]:
    """Clean success at each checkpoint, steps to the threshold and to the baseline's final success ("not
    reached" when never crossed), then those steps with their paired bootstrap intervals (`bootstrap_lines`);
    nothing when the run evaluated only its final checkpoint (no curve)."""
    conv = report.get("convergence")
    if not conv:
        return []
    steps = next(iter(conv["arms"].values()))["steps"]
    if len(steps) < 2:
        return []
    lines = [
        "## Convergence (clean success at checkpoints)",
        "",
        "| arm | " + " | ".join(str(s) for s in steps) + f" | steps to {conv['threshold']:.2f} | steps to "
        "baseline's final |",
        "|---|" + "---|" * (len(steps) + 2),
    ]
    for a, c in conv["arms"].items():
        lines.append(
            f"| {a} | "
            + " | ".join(f"{r:.2f}" for r in c["rates"])
            + f" | {_steps(c['steps_to_threshold'])} | {_steps(c.get('steps_to_baseline_final'))} |"
        )
    return [*lines, "", *bootstrap_lines(conv)]


def conditions(report: dict[str, Any]) -> list[str]:
    """The evaluation conditions in the report's order (the first arm's), e.g. ["clean", "dim:0.7"]."""
    return list(next(iter(report["success"].values())))


def success_table_lines(report: dict[str, Any]) -> list[str]:
    """Success per arm and condition, pooled over tasks and training seeds, with Wilson 95% intervals."""
    t, conds = report["success"], conditions(report)
    return [
        "| arm | " + " | ".join(conds) + " |",
        "|---|" + "---|" * len(conds),
        *[f"| {a} | " + " | ".join(fmt_cell(t[a][c]) for c in conds) + " |" for a in t],
    ]


def drop_lines(report: dict[str, Any]) -> list[str]:
    """Each arm's success under every perturbed condition minus its clean success (rate points); nothing when
    the run evaluated no perturbed condition."""
    t, conds = report["success"], conditions(report)
    if len(conds) < 2:
        return []
    return [
        "Drop from clean (success rate points):",
        "",
        "| arm | " + " | ".join(conds[1:]) + " |",
        "|---|" + "---|" * max(1, len(conds) - 1),
        *[
            f"| {a} | " + " | ".join(f"{t[a][c]['drop_from_clean']:+.2f}" for c in conds[1:]) + " |"
            for a in t
        ],
    ]


def alignment_table_lines(alignment: dict[str, dict[str, float]], keys: tuple[str, ...]) -> list[str]:
    """Attention-vs-gaze metrics per arm (rows) for those of `keys` that any arm has (columns; `-` if missing)."""
    cols = [k for k in keys if any(k in v for v in alignment.values())]
    return [
        "| arm | " + " | ".join(cols) + " |",
        "|---|" + "---|" * len(cols),
        *[
            f"| {a} | " + " | ".join(f"{v[k]:.3f}" if k in v else "-" for k in cols) + " |"
            for a, v in alignment.items()
        ],
    ]


def alignment_lines(report: dict[str, Any]) -> list[str]:
    """The report's attention-vs-gaze section on held-out frames, with how to read each metric."""
    if not report.get("alignment"):
        return []
    return [
        "## Attention vs gaze on held-out frames (unseen setups)",
        "",
        *alignment_table_lines(report["alignment"], REPORT_ALIGNMENT_KEYS),
        "",
        "KL: lower is closer to gaze; CC, SIM, NSS, AUC: higher is closer; object_mass: attention on the 3x3 patches "
        "around the task object (chance: object_mass_chance).",
        "",
    ]


def media_lines(report: dict[str, Any]) -> list[str]:
    """Figures, up to 12 rollout videos and the wall time of every stage (seconds)."""
    lines = ["## Figures", "", *[f"![{k}]({v})" for k, v in report["figures"].items()], ""]
    if report.get("videos"):
        lines += [
            "Videos (policy view | attention overlay): "
            + ", ".join(f"[{Path(v).name}]({v})" for v in report["videos"][:12]),
            "",
        ]
    return [
        *lines,
        "Stage times (s): " + ", ".join(f"{k} {v:.0f}" for k, v in report["stage_times_s"].items()),
        "",
    ]


def markdown(report: dict[str, Any]) -> str:
    """The run's report.md: every table the report holds, the verdict, figures and stage times."""
    lines = [
        *header_lines(report),
        "",
        "## Success (pooled over tasks and training seeds; Wilson 95% intervals)",
        "",
        *success_table_lines(report),
        "",
        *per_task_lines(report),
        *per_seed_lines(report),
        "",
        *drop_lines(report),
        *paired_lines(report),
        *unit_level_lines(report),
        *measure_lines(report, conditions(report)),
        *measure_lines(report, conditions(report), "stage"),
        *val_loss_lines(report),
        "",
        "## What the numbers say",
        "",
        *report["verdict"],
        "",
    ]
    lines += [*convergence_lines(report), *glc_lines(report), *alignment_lines(report), *media_lines(report)]
    return "\n".join(lines)


def headline_lines(report: dict[str, Any]) -> list[str]:
    """The head of `results_block`: one line on the run (when, where, how long, what) and the success table."""
    tr = report["train"]
    command = "make demo" if report["preset"] == "demo" else f"gazereg experiment --preset {report['preset']}"
    wall = f"wall time {report['wall_time_s'] / 60:.1f} min"
    if report.get("pooled_from"):  # one seed per folder (gazereg.experiment.pool)
        flags = "".join(f" {shlex.quote(f)}" for f in report.get("pooled_flags", []))
        command = (
            f"gazereg pool --preset {report['preset']}{flags} --arms {' '.join(tr['arms'])} "
            f"--train-seeds {' '.join(map(str, tr['seeds']))} --runs {' '.join(report['pooled_from'])}"
        )
        wall += f" summed over {len(report['pooled_from'])} runs"
    return [
        f"Latest `{report['preset']}` run: {report['date']}, {report['machine']['summary']}, {wall} "
        f"(`{command}`); {numerics_text(report['machine'])}. Tasks: {', '.join(report['tasks'])}; "
        f"{tr['steps']} training steps per arm, seeds {tr['seeds']}; "
        f"{report['eval']['episodes']} unseen setups per task and condition.",
        "",
        *success_table_lines(report),
    ]


def results_block(report: dict[str, Any], figure: str) -> str:
    """One run's results block for docs/results.md: the headline, attention vs gaze, (for several training
    seeds, or a task-level analysis) the per-task, per-seed, paired, unit-level, distance, loss and convergence
    tables, (otherwise, for more than two tasks or arms) the per-task table, the verdict and the attention
    figure at the relative path `figure`, and last the block's data line (`blockdata.BlockData`: the numerics
    key, the success counts and the attention columns, for scripts/update_results.py --check). Ends with a
    newline."""
    lines = [*headline_lines(report), ""]
    if report.get("alignment"):
        lines += [
            "Attention vs gaze on held-out frames:",
            "",
            *alignment_table_lines(report["alignment"], BLOCK_ALIGNMENT_KEYS),
            "",
        ]
    if len(report["train"]["seeds"]) > 1 or report.get("task_level"):  # the powered comparison
        lines += [
            *per_task_lines(report),
            *per_seed_lines(report),
            *paired_lines(report),
            *unit_level_lines(report),
            *measure_lines(report, conditions(report)),
            *val_loss_lines(report),
            "",
            *convergence_lines(report),
        ]
    elif len(report["tasks"]) > 2 or len(report["success"]) > 2:  # the pooled headline hides too much
        lines += [*per_task_lines(report), ""]
    stage = measure_lines(report, conditions(report), "stage")  # a staged reward: how far failures got
    lines += [*stage[1:], ""] if stage else []
    data = BlockData.of_report(report, BLOCK_ALIGNMENT_KEYS).line()
    lines += [*glc_lines(report), *report["verdict"], "", f"![attention]({figure})", data, ""]
    return "\n".join(lines)
