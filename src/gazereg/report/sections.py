"""Sections of report.md that say what ran (`header_lines`: tasks, demonstrations, evaluation setups, training)
and the glc arm's own estimators (`glc_lines`), as markdown lines from report.json (a dict); `markdown` puts
them together (`gazereg.report.markdown`).
"""

from __future__ import annotations

from typing import Any

from gazereg.runtime.hardware import PRECISION_NAMES, NumericsKey


def numerics_text(machine: dict[str, Any]) -> str:
    """How the report's runs computed, in one phrase (report.json's "machine", `tables.machine_summary`):
    `NumericsKey.describe` with the CPU model where the runs trained in one recorded precision; otherwise what
    is known (precisions that differ between runs, or none recorded: a report pooled from archives) and the CPU
    the report itself was made on, said to be that; "numerics not recorded" for a report made before the
    machine record named them. Where the runs recorded their keys when they trained ("trained_on"), the phrase
    is that key with the training CPU's model, or, for runs trained on machines whose keys differ, "trained on
    several machines: " and each key with its runs (`trained_on_text`)."""
    if machine.get("trained_on"):
        return trained_on_text(machine)
    if machine.get("numerics"):
        return NumericsKey.from_dict(machine["numerics"]).describe(machine.get("cpu_model"))
    if "cpu_capability" not in machine:
        return "numerics not recorded"
    found = sorted({p for p in machine.get("run_precisions", {}).values() if p is not None})
    if len(found) > 1:
        precision = (
            f"training precision differs between runs ({', '.join(PRECISION_NAMES.get(p, p) for p in found)})"
        )
    else:
        precision = "training precision not recorded"
    isa = ", ".join(machine["bf16_isa"]) or "none"
    return (
        f"{precision}; this report was made on a CPU with torch capability {machine['cpu_capability']} and "
        f"bf16 instructions {isa}, which need not be the one that trained"
    )


def trained_on_text(machine: dict[str, Any]) -> str:
    """The numerics the runs recorded when they trained (report.json's machine "trained_on" and
    "unrecorded_runs", `tables.machine_summary`): the one key with its CPU model(s) where every run recorded
    it; otherwise each key with its runs, and the runs that recorded none."""
    keys = machine["trained_on"]

    def described(entry: dict[str, Any]) -> str:
        models = " / ".join(entry["cpu_models"]) or None
        return NumericsKey.from_dict(entry["numerics"]).describe(models)

    if machine.get("numerics"):
        return described(keys[0])
    listed = "; ".join(f"{described(e)} (runs {', '.join(e['runs'])})" for e in keys)
    unrecorded = machine.get("unrecorded_runs") or []
    head = "trained on several machines" if len(keys) > 1 else "numerics recorded by some runs only"
    tail = f"; not recorded for (part of) {', '.join(unrecorded)}" if unrecorded else ""
    return f"{head}: {listed}{tail}"


def demos_text(demos: dict[str, Any]) -> str:
    """The training demonstrations in one phrase: episodes, frames and, where counted, the tasks that have
    fewer than wanted (the expert failed on some of their training setups) and those without any (the preset's
    `tasks_without_demos`: evaluated, never trained on), and, for a pool of folders whose demonstrations were
    collected on different machines (`gazereg pool --demos-across-machines`), each folder's frames."""
    text = f"{demos['episodes']} episodes ({demos['frames']} frames) on training setups"
    if "frames_per_folder" in demos:
        each = ", ".join(map(str, demos["frames_per_folder"]))
        text += (
            f" (collected again in each pooled folder from the same setups and seeds, on different machines: "
            f"{each} frames)"
        )
    if "per_task" not in demos:
        return text
    without = demos.get("without", [])
    none = f"; none of {', '.join(without)} (the expert cannot demonstrate it: evaluated, never trained on)"
    tail = none if without else ""
    short = {t: n for t, n in demos["per_task"].items() if n < demos["wanted"] and t not in without}
    if not short:
        return f"{text}, {demos['wanted']} per task{tail}"
    fewer = ", ".join(f"{t} {n}" for t, n in short.items())
    return f"{text}, {demos['wanted']} per task but fewer where the expert failed ({fewer}){tail}"


def eval_text(ev: dict[str, Any]) -> str:
    """The evaluation setups in one phrase."""
    text = f"{ev['episodes']} unseen setups per task and condition (seeds {ev['seeds']})"
    if ev.get("robustness_episodes") is None:
        return text
    return (
        f"{ev['episodes']} unseen setups per task clean (seeds {ev['seeds']}) and the first "
        f"{ev['robustness_episodes']} of them under every other condition"
    )


def header_lines(report: dict[str, Any]) -> list[str]:
    """The report's title, when and where it ran, and what was trained and evaluated."""
    ev, tr = report["eval"], report["train"]
    pooled = report.get("pooled_from")
    return [
        f"# gazereg experiment: preset `{report['preset']}`",
        "",
        f"{report['date']} on {report['machine']['summary']}; {numerics_text(report['machine'])}; "
        f"wall time {report['wall_time_s'] / 60:.1f} min"
        + (
            f", summed over {len(pooled)} runs pooled by `gazereg pool`: {', '.join(pooled)}."
            if pooled
            else "."
        ),
        "",
        f"Tasks: {', '.join(report['tasks'])}. Demonstrations: {demos_text(report['demos'])}; evaluation on "
        f"{eval_text(ev)}, identical for every arm. Training: "
        f"{tr['steps']} steps, batch {tr['batch_size']}, seeds {tr['seeds']}; {gaze_term_text(tr)}.",
    ]


def gaze_term_text(train: dict[str, Any]) -> str:
    """The gaze term's settings as report.json's "train" states them, or that no arm trains with one."""
    arms = train.get("gaze_arms")
    if arms == []:
        return "no arm has a gaze term"
    queries = f", {train['gaze_queries']} queries" if "gaze_queries" in train else ""
    on = f" (arms {', '.join(arms)})" if arms else ""
    return f"gaze weight {train['gaze_weight']} on layers {train['gaze_layers']}{queries}{on}"


def glc_lines(report: dict[str, Any]) -> list[str]:
    """The glc arm's own estimator: its held-out F1 next to a centre prior and uniform gaze (per fold when
    cross-fitted)."""
    glc = report.get("glc")
    if glc and glc.get("folds"):
        return glc_folds_lines(glc)
    if not glc or not glc.get("eval"):
        return []
    g = glc["eval"]
    auc = (
        f"; AUC {g['glc_auc']:.3f} (centre prior {g['centre_prior_auc']:.3f}, uniform {g['uniform_auc']:.3f})"
        if "glc_auc" in g
        else ""
    )
    return [
        "## The glc arm's estimator",
        "",
        f"A small GLC trained here for {glc['steps']} steps on other setups' simulated gaze; on its "
        f"held-out episodes {g['heldout']}: F1 {g['glc_f1']:.3f} (centre prior {g['centre_prior_f1']:.3f}, "
        f"uniform {g['uniform_f1']:.3f}){auc}.",
        "",
    ]


def glc_folds_lines(glc: dict[str, Any]) -> list[str]:
    """The cross-fitted GLCs: per fold, the tasks it predicts and its quality on their episodes."""
    lines = [
        "## The glc arm's estimators (cross-fitted)",
        "",
        "Each task's glc prior comes from a small GLC trained on the simulated gaze of the other tasks' training "
        "demonstrations only; scored on episodes of the tasks it predicts (F1 and AUC; the centre prior is "
        "fitted on its training tasks' gaze):",
        "",
        "| predicts | steps | episodes | GLC F1 | centre prior F1 | uniform F1 | GLC AUC | centre prior AUC |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for fold in glc["folds"]:
        g = fold.get("eval")
        scores = (
            f"{len(g['heldout'])} | {g['glc_f1']:.3f} | {g['centre_prior_f1']:.3f} | {g['uniform_f1']:.3f} | "
            f"{g['glc_auc']:.3f} | {g['centre_prior_auc']:.3f}"
            if g
            else "0 | - | - | - | - | -"
        )
        lines.append(f"| {', '.join(fold['predicts'])} | {fold['steps']} | {scores} |")
    return [*lines, ""]
