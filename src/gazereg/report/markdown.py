"""The experiment's report as text: report.md and the README's results blocks."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def fmt_cell(c: dict[str, Any]) -> str:
    return f"{c['successes']}/{c['n']} = {c['rate']:.2f} [{c['ci95'][0]:.2f}, {c['ci95'][1]:.2f}]"


def per_task_lines(report: dict[str, Any], condition: str = "clean") -> list[str]:
    """Successes per task under `condition`, one row per arm (pooled over training seeds), Wilson 95%."""
    t, tasks = report["success"], report["tasks"]
    lines = [
        f"Per task ({condition}):",
        "",
        "| arm | " + " | ".join(tasks) + " |",
        "|---|" + "---|" * len(tasks),
    ]
    for a in t:
        pt = t[a][condition]["per_task"]
        lines.append(
            f"| {a} | "
            + " | ".join(
                f"{pt[k]['successes']}/{pt[k]['n']} [{pt[k]['ci95'][0]:.2f}, {pt[k]['ci95'][1]:.2f}]"
                for k in tasks
            )
            + " |"
        )
    return lines


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


def rate_difference(test: dict[str, Any]) -> str:
    """A paired test's success-rate difference and its 95% interval, e.g. `+0.12 [+0.05, +0.19]`; `n/a` for
    reports written before it was computed."""
    if "rate_diff" not in test:
        return "n/a"
    lo, hi = test["rate_ci95"]
    return f"{test['rate_diff']:+.2f} [{lo:+.2f}, {hi:+.2f}]"


def paired_lines(report: dict[str, Any]) -> list[str]:
    """Each arm against the baseline on the same setups: the paired success difference with its interval,
    exact McNemar and Fisher p-values."""
    if not report.get("paired"):
        return []
    lines = [
        "",
        "## Paired comparisons (same setups; exact McNemar on discordant episodes, Fisher on counts)",
        "",
        "| comparison (A vs B) | condition | pairs | only A solved | only B solved | success A - B [95% CI] "
        "| McNemar p | Fisher p |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for k, v in report["paired"].items():
        comparison, condition = k.split(" | ", 1)
        a, b = comparison.split(" vs ", 1)
        lines.append(
            f"| {comparison} | {condition} | {v['pairs']} | {v[f'{a}_only']} | {v[f'{b}_only']} | "
            f"{rate_difference(v)} | {v['mcnemar_p']:.3f} | {v['fisher_p']:.3f} |"
        )
    return lines


def val_loss_lines(report: dict[str, Any]) -> list[str]:
    """Each arm's final action loss on its run's validation episodes (demonstrations held out of training, on
    training setups; a run's seed fixes the split, so arms with the same seed share it)."""
    runs = {k: v for k, v in (report.get("val_loss") or {}).items() if v is not None}
    if not runs:
        return []
    by_arm: dict[str, dict[str, float]] = {}
    for name, v in runs.items():
        arm, _, seed = name.partition("@")
        by_arm.setdefault(arm, {})[seed or "-"] = v
    seeds = sorted({s for d in by_arm.values() for s in d})
    lines = [
        "",
        "## Action loss on held-out demonstrations (end of training; lower is better)",
        "",
        "| arm | " + " | ".join(seeds) + " | mean |",
        "|---|" + "---|" * (len(seeds) + 1),
    ]
    for arm, d in by_arm.items():
        cells = [f"{d[s]:.4f}" if s in d else "-" for s in seeds]
        lines.append(f"| {arm} | " + " | ".join(cells) + f" | {sum(d.values()) / len(d):.4f} |")
    return lines


def convergence_lines(report: dict[str, Any]) -> list[str]:
    """Clean success at each checkpoint, steps to the threshold and to the baseline's final success."""
    conv = report.get("convergence")
    if not conv:
        return []
    steps = next(iter(conv["arms"].values()))["steps"]
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
            + f" | {c['steps_to_threshold']} | {c.get('steps_to_baseline_final')} |"
        )
    return [*lines, ""]


def distance_lines(report: dict[str, Any], conds: list[str]) -> list[str]:
    """The closest-approach table and its paired comparisons, when the report has them."""
    dist = report.get("distance")
    if not dist or not dist.get("table"):
        return []
    table = dist["table"]
    lines = [
        "",
        "## Closest approach to the target (metres; lower is better)",
        "",
        "Per episode, the smallest distance of the object (the hand, for reach) to its target that the "
        "simulator measured: a continuous outcome that moves before success does. Mean [95% interval]:",
        "",
        "| arm | " + " | ".join(conds) + " |",
        "|---|" + "---|" * len(conds),
    ]
    for a, row in table.items():
        cells = [
            f"{row[c]['mean']:.4f} [{row[c]['ci95'][0]:.4f}, {row[c]['ci95'][1]:.4f}]" if c in row else "-"
            for c in conds
        ]
        lines.append(f"| {a} | " + " | ".join(cells) + " |")
    if dist.get("paired"):
        lines += [
            "",
            "| comparison | condition | pairs | mean difference [95% interval] | permutation p |",
            "|---|---|---|---|---|",
        ]
        for k, v in dist["paired"].items():
            comparison, condition = k.split(" | ", 1)
            lines.append(
                f"| {comparison} | {condition} | {v['n']} | {v['mean_diff']:+.4f} "
                f"[{v['ci95'][0]:+.4f}, {v['ci95'][1]:+.4f}] | {v['p_value']:.4f} |"
            )
    return lines


def markdown(report: dict[str, Any]) -> str:
    t = report["success"]
    arms = list(t)
    conds = list(next(iter(t.values())))
    lines = [
        f"# gazereg experiment: preset `{report['preset']}`",
        "",
        f"{report['date']} on {report['machine']['summary']}; wall time {report['wall_time_s'] / 60:.1f} min.",
        "",
        f"Tasks: {', '.join(report['tasks'])}. Demonstrations: {report['demos']['episodes']} episodes "
        f"({report['demos']['frames']} frames) on training setups; evaluation on {report['eval']['episodes']} unseen setups "
        f"per task and condition (seeds {report['eval']['seeds']}), identical for every arm. Training: "
        f"{report['train']['steps']} steps, batch {report['train']['batch_size']}, seeds {report['train']['seeds']}; "
        f"gaze weight {report['train']['gaze_weight']} on layers {report['train']['gaze_layers']}.",
        "",
        "## Success (pooled over tasks and training seeds; Wilson 95% intervals)",
        "",
        "| arm | " + " | ".join(conds) + " |",
        "|---|" + "---|" * len(conds),
    ]
    lines += [f"| {a} | " + " | ".join(fmt_cell(t[a][c]) for c in conds) + " |" for a in arms]
    lines += ["", *per_task_lines(report), *per_seed_lines(report)]
    lines += [
        "",
        "Drop from clean (success rate points):",
        "",
        "| arm | " + " | ".join(conds[1:]) + " |",
        "|---|" + "---|" * max(1, len(conds) - 1),
    ]
    lines += [
        f"| {a} | " + " | ".join(f"{t[a][c]['drop_from_clean']:+.2f}" for c in conds[1:]) + " |" for a in arms
    ]
    lines += paired_lines(report)
    lines += distance_lines(report, conds)
    lines += val_loss_lines(report)
    lines += ["", "## What the numbers say", "", *report["verdict"], ""]
    lines += convergence_lines(report)
    if report.get("glc") and report["glc"].get("eval"):
        g = report["glc"]["eval"]
        lines += [
            "## The glc arm's estimator",
            "",
            f"A small GLC trained here for {report['glc']['steps']} steps on other setups' simulated gaze; on its "
            f"held-out episodes {g['heldout']}: F1 {g['glc_f1']:.3f} (centre prior {g['centre_prior_f1']:.3f}, "
            f"uniform {g['uniform_f1']:.3f}).",
            "",
        ]
    if report.get("alignment"):
        al = report["alignment"]
        keys = [
            k
            for k in (
                "gaze_kl",
                "gaze_cc",
                "gaze_sim",
                "gaze_nss",
                "gaze_auc_judd",
                "object_mass",
                "object_mass_chance",
            )
            if any(k in v for v in al.values())
        ]
        lines += [
            "## Attention vs gaze on held-out frames (unseen setups)",
            "",
            "| arm | " + " | ".join(keys) + " |",
            "|---|" + "---|" * len(keys),
        ]
        for a, v in al.items():
            lines.append(f"| {a} | " + " | ".join(f"{v[k]:.3f}" if k in v else "-" for k in keys) + " |")
        lines += [
            "",
            "KL: lower is closer to gaze; CC, SIM, NSS, AUC: higher is closer; object_mass: attention on the 3x3 patches "
            "around the task object (chance: object_mass_chance).",
            "",
        ]
    lines += ["## Figures", ""] + [f"![{k}]({v})" for k, v in report["figures"].items()] + [""]
    if report.get("videos"):
        lines += [
            "Videos (policy view | attention overlay): "
            + ", ".join(f"[{Path(v).name}]({v})" for v in report["videos"][:12]),
            "",
        ]
    lines += ["Stage times (s): " + ", ".join(f"{k} {v:.0f}" for k, v in report["stage_times_s"].items()), ""]
    return "\n".join(lines)


def readme_block(report: dict[str, Any], figure: str) -> str:
    """The README's results block for one experiment report (everything from the report itself)."""
    t = report["success"]
    conds = list(next(iter(t.values())))
    command = (
        "make demo" if report["preset"] == "quick" else f"gazereg experiment --preset {report['preset']}"
    )
    lines = [
        f"Latest `{report['preset']}` run: {report['date']}, {report['machine']['summary']}, wall time "
        f"{report['wall_time_s'] / 60:.1f} min (`{command}`). Tasks: {', '.join(report['tasks'])}; "
        f"{report['train']['steps']} training steps per arm, seeds {report['train']['seeds']}; "
        f"{report['eval']['episodes']} unseen setups per task and condition.",
        "",
        "| arm | " + " | ".join(conds) + " |",
        "|---|" + "---|" * len(conds),
        *[f"| {a} | " + " | ".join(fmt_cell(t[a][c]) for c in conds) + " |" for a in t],
        "",
    ]
    if report.get("alignment"):
        keys = [
            k
            for k in ("gaze_kl", "gaze_cc", "gaze_auc_judd", "object_mass", "object_mass_chance")
            if any(k in v for v in report["alignment"].values())
        ]
        lines += [
            "Attention vs gaze on held-out frames:",
            "",
            "| arm | " + " | ".join(keys) + " |",
            "|---|" + "---|" * len(keys),
        ]
        lines += [
            f"| {a} | " + " | ".join(f"{v[k]:.3f}" if k in v else "-" for k in keys) + " |"
            for a, v in report["alignment"].items()
        ]
        lines.append("")
    if len(report["train"]["seeds"]) > 1:  # the powered comparison: per task, paired tests, distances
        conds = list(next(iter(report["success"].values())))
        lines += [
            *per_task_lines(report),
            *per_seed_lines(report),
            *paired_lines(report),
            *distance_lines(report, conds),
            *val_loss_lines(report),
            "",
            *convergence_lines(report),
        ]
    lines += [*report["verdict"], "", f"![attention]({figure})", ""]
    return "\n".join(lines)


def replace_block(readme: Path, marker: str, block: str) -> None:
    """Replace the README's text between `<!-- {marker}:start -->` and `<!-- {marker}:end -->` with `block`."""
    from gazereg.runtime.io import atomic_write_text

    start, end = f"<!-- {marker}:start -->", f"<!-- {marker}:end -->"
    text = readme.read_text()
    if start not in text or end not in text:
        raise ValueError(f"{readme} has no {start} ... {end} block")
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    atomic_write_text(readme, f"{head}{start}\n{block}{end}{tail}")


def update_readme(readme: Path, run_dir: Path, figure_dir: Path, marker: str = "quick-results") -> None:
    """Replace the README's block between `<!-- {marker}:start -->` and `<!-- {marker}:end -->` with the
    results of the experiment in `run_dir`, copying its attention figure into `figure_dir`."""
    import json
    import shutil

    report = json.loads((run_dir / "report.json").read_text())
    figure_dir.mkdir(parents=True, exist_ok=True)
    fig = figure_dir / f"{marker}-attention.png"
    shutil.copyfile(run_dir / report["figures"]["attention"], fig)
    replace_block(readme, marker, readme_block(report, str(fig.relative_to(readme.parent))))
