"""The experiment's report: success tables with intervals, robustness, convergence, alignment, figures.

Everything here is computed from the experiment's own records (evaluation episodes, training metrics,
attention maps); no number is typed in. Arms trained with several seeds are pooled over seeds (their
evaluation episodes pair by training seed, task and setup seed).
"""

from __future__ import annotations

import platform
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from gazevla.stats import fisher_exact, mcnemar_exact, steps_to_threshold, wilson


def base_arm(name: str) -> str:
    return name.split("@", 1)[0]


def success_table(records: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, Any]]]:
    """{arm: {condition: {successes, n, rate, ci95, per_task: {...}}}} pooled over training seeds."""
    cells: dict[tuple[str, str, str], list[bool]] = defaultdict(list)
    for r in records:
        cells[(base_arm(r["arm"]), r["condition"], r["task"])].append(bool(r["success"]))
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for (arm, cond, task), xs in sorted(cells.items()):
        c = out.setdefault(arm, {}).setdefault(cond, {"successes": 0, "n": 0, "per_task": {}})
        c["successes"] += sum(xs)
        c["n"] += len(xs)
        c["per_task"][task] = {"successes": sum(xs), "n": len(xs), "ci95": list(wilson(sum(xs), len(xs)))}
    for arm in out.values():
        for c in arm.values():
            c["rate"] = c["successes"] / c["n"]
            c["ci95"] = list(wilson(c["successes"], c["n"]))
        if "clean" in arm:
            for c in arm.values():
                c["drop_from_clean"] = arm["clean"]["rate"] - c["rate"]
    return out


def paired_tests(records: list[dict[str, Any]], reference: str = "baseline") -> dict[str, dict[str, Any]]:
    """Each arm against `reference` per condition: exact McNemar on episodes paired by (training seed, task,
    setup seed), and Fisher's exact test on the pooled counts."""
    key = defaultdict(dict)
    for r in records:
        arm, _, seed = r["arm"].partition("@")
        key[(arm, r["condition"])][(seed, r["task"], r["seed"])] = bool(r["success"])
    out = {}
    arms = sorted({a for a, _ in key} - {reference})
    for arm in arms:
        for (a, cond), outcomes in key.items():
            if a != arm or (reference, cond) not in key:
                continue
            ref = key[(reference, cond)]
            common = sorted(set(outcomes) & set(ref))
            if not common:
                continue
            x, y = [outcomes[k] for k in common], [ref[k] for k in common]
            m = mcnemar_exact(x, y)
            out[f"{arm} vs {reference} | {cond}"] = {
                "pairs": len(common),
                f"{arm}_only": m["a_only"],
                f"{reference}_only": m["b_only"],
                "mcnemar_p": m["p_value"],
                "fisher_p": fisher_exact(sum(x), len(x), sum(y), len(y)),
            }
    return out


def convergence(curves: dict[str, dict[int, tuple[int, int]]], threshold: float) -> dict[str, Any]:
    """curves: {arm: {step: (successes, n)}} -> rates, steps to `threshold`, and each arm's steps to reach the
    baseline's final success rate."""
    out: dict[str, Any] = {"threshold": threshold, "arms": {}}
    for arm, pts in curves.items():
        steps = sorted(pts)
        rates = [pts[s][0] / pts[s][1] for s in steps]
        out["arms"][arm] = {
            "steps": steps,
            "rates": rates,
            "ci95": [list(wilson(*pts[s])) for s in steps],
            "steps_to_threshold": steps_to_threshold(steps, rates, threshold),
        }
    if "baseline" in out["arms"] and out["arms"]["baseline"]["rates"]:
        final = out["arms"]["baseline"]["rates"][-1]
        out["baseline_final"] = final
        for c in out["arms"].values():
            c["steps_to_baseline_final"] = (
                steps_to_threshold(c["steps"], c["rates"], final) if final > 0 else None
            )
    return out


def overlap(a: list[float], b: list[float]) -> bool:
    return a[0] <= b[1] and b[0] <= a[1]


# ----- figures ---------------------------------------------------------------------------------------------
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_success(table: dict[str, dict[str, dict[str, Any]]], path: Path) -> Path:
    plt = _plt()
    arms = list(table)
    conds = list(next(iter(table.values())))
    width = 0.8 / max(len(arms), 1)
    fig, ax = plt.subplots(figsize=(1.6 + 1.4 * len(conds), 3.2))
    for i, arm in enumerate(arms):
        x = np.arange(len(conds)) + (i - (len(arms) - 1) / 2) * width
        rates = [table[arm][c]["rate"] for c in conds]
        lo = [table[arm][c]["rate"] - table[arm][c]["ci95"][0] for c in conds]
        hi = [table[arm][c]["ci95"][1] - table[arm][c]["rate"] for c in conds]
        ax.bar(x, rates, width, yerr=[lo, hi], capsize=3, label=arm)
    ax.set_xticks(np.arange(len(conds)), conds, rotation=15)
    ax.set_ylim(0, 1)
    ax.set_ylabel("success rate (Wilson 95%)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_convergence(
    conv: dict[str, Any], losses: dict[str, list[tuple[int, float, float | None]]], path: Path
) -> Path:
    """Success vs steps (clean), training action loss, and each gaze arm's held-out KL to its own prior."""
    plt = _plt()
    arms = list(dict.fromkeys([*conv["arms"], *losses]))
    color = {arm: f"C{i}" for i, arm in enumerate(arms)}  # one colour per arm in every panel
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.2))
    for arm, c in conv["arms"].items():
        ci = np.array(c["ci95"])
        axes[0].plot(c["steps"], c["rates"], marker="o", label=arm, color=color[arm])
        axes[0].fill_between(c["steps"], ci[:, 0], ci[:, 1], alpha=0.15, color=color[arm])
    axes[0].set(xlabel="training step", ylabel="success (clean)", ylim=(0, 1), title="success vs steps")
    for arm, pts in losses.items():
        if not pts:
            continue
        s = [p[0] for p in pts]
        axes[1].plot(s, [p[1] for p in pts], label=arm, color=color[arm])
        kl = [(p[0], p[2]) for p in pts if p[2] is not None]
        if kl:
            axes[2].plot(*zip(*kl), label=arm, color=color[arm])
    axes[1].set(xlabel="training step", ylabel="action loss (L1, normalised)", title="training loss")
    axes[2].set(
        xlabel="training step", ylabel="KL(own prior || attention)", title="held-out KL to the arm's prior"
    )
    for ax in axes:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_attention(panels: list[dict[str, Any]], columns: list[str], path: Path) -> Path:
    """panels: one row each: {"title": str, "frame": (H, W, 3) uint8, column: (H, W) heat or None}."""
    from gazevla.viz.overlay import overlay

    plt = _plt()
    cols = ["observation", *columns]
    fig, axes = plt.subplots(
        len(panels), len(cols), figsize=(2.1 * len(cols), 2.2 * len(panels)), squeeze=False
    )
    for i, row in enumerate(panels):
        for j, col in enumerate(cols):
            ax = axes[i, j]
            img = (
                row["frame"]
                if col == "observation" or row.get(col) is None
                else overlay(row["frame"], row[col])
            )
            ax.imshow(img)
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(col, fontsize=9)
        axes[i, 0].set_ylabel(row["title"], fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


# ----- markdown ----------------------------------------------------------------------------------------------
def fmt_cell(c: dict[str, Any]) -> str:
    return f"{c['successes']}/{c['n']} = {c['rate']:.2f} [{c['ci95'][0]:.2f}, {c['ci95'][1]:.2f}]"


def markdown(report: dict[str, Any]) -> str:
    t = report["success"]
    arms = list(t)
    conds = list(next(iter(t.values())))
    lines = [
        f"# gazevla experiment: preset `{report['preset']}`",
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
    lines += [
        "",
        "Per task (clean):",
        "",
        "| arm | " + " | ".join(report["tasks"]) + " |",
        "|---|" + "---|" * len(report["tasks"]),
    ]
    for a in arms:
        pt = t[a]["clean"]["per_task"]
        lines.append(
            f"| {a} | " + " | ".join(f"{pt[k]['successes']}/{pt[k]['n']}" for k in report["tasks"]) + " |"
        )
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
    if report.get("paired"):
        lines += [
            "",
            "## Paired comparisons (same setups; exact McNemar on discordant episodes, Fisher on counts)",
            "",
            "| comparison | condition | pairs | arm only | baseline only | McNemar p | Fisher p |",
            "|---|---|---|---|---|---|---|",
        ]
        for k, v in report["paired"].items():
            comparison, condition = k.split(" | ", 1)
            vals = list(v.values())
            lines.append(
                f"| {comparison} | {condition} | {vals[0]} | {vals[1]} | {vals[2]} | {v['mcnemar_p']:.3f} | {v['fisher_p']:.3f} |"
            )
    lines += ["", "## What the numbers say", "", *report["verdict"], ""]
    if report.get("convergence"):
        conv = report["convergence"]
        lines += [
            "## Convergence (clean success at checkpoints)",
            "",
            "| arm | "
            + " | ".join(str(s) for s in next(iter(conv["arms"].values()))["steps"])
            + " | steps to "
            f"{conv['threshold']:.2f} | steps to baseline's final |",
            "|---|" + "---|" * (len(next(iter(conv["arms"].values()))["steps"]) + 2),
        ]
        for a, c in conv["arms"].items():
            lines.append(
                f"| {a} | "
                + " | ".join(f"{r:.2f}" for r in c["rates"])
                + f" | {c['steps_to_threshold']} | {c.get('steps_to_baseline_final')} |"
            )
        lines.append("")
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


def verdict(success: dict[str, Any], reference: str = "baseline") -> list[str]:
    """Plain sentences on what the intervals allow one to conclude."""
    out = []
    if reference not in success:
        return ["No baseline arm: no comparison."]
    for arm in success:
        if arm == reference:
            continue
        for cond, c in success[arm].items():
            r = success[reference][cond]
            diff = c["rate"] - r["rate"]
            if overlap(c["ci95"], r["ci95"]):
                out.append(
                    f"- {arm} vs {reference}, {cond}: {c['rate']:.2f} vs {r['rate']:.2f} ({diff:+.2f}); the 95% intervals overlap, so this budget does not decide it."
                )
            else:
                better = "better" if diff > 0 else "worse"
                out.append(
                    f"- {arm} vs {reference}, {cond}: {c['rate']:.2f} vs {r['rate']:.2f} ({diff:+.2f}); the intervals do not overlap: {arm} is {better}."
                )
    return out


def machine_summary() -> dict[str, Any]:
    import os

    import torch

    return {
        "summary": f"{platform.machine()} CPU, {os.cpu_count()} cores, torch {torch.__version__}, Python {platform.python_version()}",
        "cores": os.cpu_count(),
        "torch": torch.__version__,
        "python": platform.python_version(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
    }


def readme_block(report: dict[str, Any], figure: str) -> str:
    """The README's results block for one experiment report (everything from the report itself)."""
    t = report["success"]
    conds = list(next(iter(t.values())))
    lines = [
        f"Latest `{report['preset']}` run: {report['date']}, {report['machine']['summary']}, wall time "
        f"{report['wall_time_s'] / 60:.1f} min (`make demo`). Tasks: {', '.join(report['tasks'])}; "
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
    lines += [*report["verdict"], "", f"![attention]({figure})", ""]
    return "\n".join(lines)


def update_readme(readme: Path, run_dir: Path, figure_dir: Path, marker: str = "quick-results") -> None:
    """Replace the README's block between `<!-- {marker}:start -->` and `<!-- {marker}:end -->` with the
    results of the experiment in `run_dir`, copying its attention figure into `figure_dir`."""
    import json
    import shutil

    from gazevla.utils.io import atomic_write_text

    report = json.loads((run_dir / "report.json").read_text())
    figure_dir.mkdir(parents=True, exist_ok=True)
    fig = figure_dir / f"{marker}-attention.png"
    shutil.copyfile(run_dir / report["figures"]["attention"], fig)
    start, end = f"<!-- {marker}:start -->", f"<!-- {marker}:end -->"
    text = readme.read_text()
    if start not in text or end not in text:
        raise ValueError(f"{readme} has no {start} ... {end} block")
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    block = readme_block(report, str(fig.relative_to(readme.parent)))
    atomic_write_text(readme, f"{head}{start}\n{block}{end}{tail}")
