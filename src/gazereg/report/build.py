"""The experiment's report: every table, test and curve of report.json, and its figures, from the stages'
records.

    report = build_report(spec, outputs, out)    # draws out/figures/{success,convergence}.png
    write_report(out, report)                    # out/report.json and out/report.md

`ReportSpec` says what the experiment ran (from its configuration), `StageOutputs` what its stages produced
(evaluation records, training metrics, alignment); the experiment's runner fills both.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gazereg.report.convergence import ConvergencePoint, convergence_report
from gazereg.report.figures import plot_convergence, plot_success
from gazereg.report.ids import RunId
from gazereg.report.markdown import markdown
from gazereg.report.progress import progress_sections
from gazereg.report.tables import (
    machine_summary,
    paired_tests,
    per_seed_table,
    per_task_paired_tests,
    run_of,
    success_table,
    unit_level_tests,
    verdict,
)
from gazereg.runtime.io import atomic_write_json, atomic_write_text
from gazereg.training.arms import gaze_controls
from gazereg.training.logger import read_metrics
from gazereg.training.numerics import TrainingAttempt

MIN_TASK_LEVEL_TASKS = 3
"""the fewest tasks for which the report takes the task as the unit too (with two, the t interval has one
degree of freedom and the sign-flip test's smallest p is 0.5: the per-task table says as much)"""

Record = dict[str, Any]
"""one evaluation episode as `evaluation.rollout` writes it: arm (a `RunId`'s text), task, condition, seed
(the setup), success, and min_distance / max_reward / video where recorded"""


@dataclass(frozen=True)
class ReportSpec:
    """What the experiment ran, as its report states it."""

    preset: str
    tasks: tuple[str, ...]
    arms: tuple[str, ...]
    train_seeds: tuple[int, ...]
    train_steps: int
    batch_size: int
    gaze_weight: float
    gaze_layers: tuple[int, ...]
    eval_episodes: int
    """unseen setups per task and condition, seeds eval_seed_start.."""
    eval_conditions: tuple[str, ...]
    eval_seed_start: int
    convergence_episodes: int
    """setups per task evaluated at each intermediate checkpoint (the first of the final evaluation's)"""
    threshold: float
    """success rate whose first crossing is reported as 'steps to threshold'"""
    config: dict[str, Any]
    """the resolved configuration, stored in report.json as it is"""
    eval_robustness_episodes: int | None = None
    """setups per task under each condition but clean (the first of the clean ones); None: eval_episodes"""
    gaze_queries: str = "action"
    """whose attention the gaze term supervises (`GazeConfig.queries`)"""
    gaze_arms: tuple[str, ...] | None = None
    """the arms that train with a gaze term (a prior); None: not stated (the report then names the term's
    settings whatever the arms)"""


@dataclass(frozen=True)
class StageOutputs:
    """What the experiment's stages produced, as the report reads it."""

    episodes: list[Record]
    """the final checkpoints' evaluation, every condition"""
    checkpoint_episodes: list[Record]
    """the intermediate checkpoints' clean evaluation (their runs name their step); empty when none"""
    demos: dict[str, Any]
    """the training demonstrations: {"episodes", "frames"} and, where recorded, {"wanted": per task,
    "per_task": {task: episodes}, "without": [tasks without demonstrations]}"""
    glc: dict[str, Any] | None
    """the GLC the experiment trained for the glc arm (checkpoint, steps, eval; or "folds", one such record per
    cross-fitted GLC with the tasks it "trained_on" and "predicts"), or None"""
    final_metrics: dict[RunId, dict[str, float]]
    """each run's metrics at its last training step"""
    metrics_files: dict[RunId, Path]
    """each run's training metrics (metrics.jsonl)"""
    alignment: dict[RunId, dict[str, float]]
    """each run's attention-versus-gaze metrics on held-out frames"""
    attention_figure: str
    """the align stage's figure, relative to the run folder"""
    date: str
    stage_times: dict[str, float]
    """seconds per finished stage"""
    numerics: dict[RunId, tuple[TrainingAttempt, ...] | None] = field(default_factory=dict)
    """each run's training attempts as its numerics.json recorded them (`training.numerics`), None for a run
    that has none; the report names their machines (`tables.machine_summary`); empty: none recorded"""


def build_report(spec: ReportSpec, outputs: StageOutputs, out: Path) -> dict[str, Any]:
    """report.json's content; draws the success and convergence figures into `out/figures`."""
    episodes = outputs.episodes
    success = success_table(episodes)
    # Each arm against the baseline, and the gaze arm against each of its controls it ran with (the arms whose
    # registered role is a control: gazereg.training.arms).
    controls = {c: gaze_and_control(episodes, spec.arms, c) for c in gaze_controls(spec.arms)}
    controls = {c: records for c, records in controls.items() if records}
    paired = paired_tests(episodes)
    several_tasks = len(spec.tasks) > 1
    per_task = per_task_paired_tests(episodes) if several_tasks else {}
    levels = {"seed": unit_level_tests(episodes, "seed")}
    if len(spec.tasks) >= MIN_TASK_LEVEL_TASKS:
        levels["task"] = unit_level_tests(episodes, "task")
    verdicts = verdict(success, paired=paired, levels=levels)
    for control, records in controls.items():
        paired.update(paired_tests(records, control))
        if several_tasks:
            per_task.update(per_task_paired_tests(records, control))
        for unit, tests in levels.items():
            tests.update(unit_level_tests(records, unit, control))
        verdicts += verdict(success_table(records), control, paired, levels=levels)
    conv = convergence_report(_convergence_points(spec, outputs), spec.threshold)
    figs = out / "figures"
    figs.mkdir(parents=True, exist_ok=True)
    plot_success(success, figs / "success.png")
    plot_convergence(conv, _training_losses(spec, outputs.metrics_files), figs / "convergence.png")
    return {
        **_header(spec, outputs),
        "success": success,
        "paired": paired,
        "paired_per_task": per_task or None,
        "per_seed": per_seed_table(episodes) if len(spec.train_seeds) > 1 else None,
        "seed_level": levels["seed"] or None,
        "task_level": levels.get("task") or None,
        **progress_sections(episodes, controls),
        "verdict": verdicts,
        "convergence": conv,
        "glc": outputs.glc,
        "val_loss": {str(run): m.get("val/loss_action") for run, m in outputs.final_metrics.items()},
        "alignment": {
            run.arm if len(spec.train_seeds) == 1 else str(run): v for run, v in outputs.alignment.items()
        },
        "figures": {
            "success": "figures/success.png",
            "convergence": "figures/convergence.png",
            "attention": outputs.attention_figure,
        },
        "videos": [os.path.relpath(e["video"], out) for e in episodes if e.get("video")],  # ../ when pooled
        "config": spec.config,
    }


def write_report(out: Path, report: dict[str, Any]) -> Path:
    """out/report.json and out/report.md; returns the markdown's path."""
    atomic_write_json(out / "report.json", report)
    atomic_write_text(out / "report.md", markdown(report))
    return out / "report.md"


def trained_precisions(metrics_files: dict[RunId, Path]) -> dict[str, str | None]:
    """{run: the precision it trained in} ("no" = float32, "bf16", "fp16"), as the config.json beside its
    metrics.jsonl records it (the trainer saves its configuration after resolving "auto"); None for a run
    whose folder has no config.json (an archive keeps only the metrics)."""
    out: dict[str, str | None] = {}
    for run, metrics in sorted(metrics_files.items(), key=lambda item: str(item[0])):
        config = metrics.parent / "config.json"
        out[str(run)] = str(json.loads(config.read_text())["mixed_precision"]) if config.is_file() else None
    return out


def _header(spec: ReportSpec, outputs: StageOutputs) -> dict[str, Any]:
    """What ran, where and for how long."""
    return {
        "preset": spec.preset,
        "date": outputs.date,
        "machine": machine_summary(
            trained_precisions(outputs.metrics_files), {str(run): a for run, a in outputs.numerics.items()}
        ),
        "wall_time_s": sum(outputs.stage_times.values()),
        "stage_times_s": dict(outputs.stage_times),
        "tasks": list(spec.tasks),
        "demos": {
            "episodes": outputs.demos.get("episodes"),
            "frames": outputs.demos.get("frames"),
            **{
                k: outputs.demos[k]
                for k in ("wanted", "per_task", "without", "instructions", "frames_per_folder")
                if k in outputs.demos
            },
        },
        "train": {
            "steps": spec.train_steps,
            "batch_size": spec.batch_size,
            "seeds": list(spec.train_seeds),
            "gaze_weight": spec.gaze_weight,
            "gaze_layers": list(spec.gaze_layers),
            "gaze_queries": spec.gaze_queries,
            **({} if spec.gaze_arms is None else {"gaze_arms": list(spec.gaze_arms)}),
            "arms": list(spec.arms),
        },
        "eval": {
            "episodes": spec.eval_episodes,
            "conditions": list(spec.eval_conditions),
            "seeds": f"{spec.eval_seed_start}..{spec.eval_seed_start + spec.eval_episodes - 1}",
            **(
                {"robustness_episodes": spec.eval_robustness_episodes}
                if spec.eval_robustness_episodes is not None
                else {}
            ),
        },
    }


def __getattr__(name: str) -> Any:
    """`GAZE_CONTROLS`: every registered arm whose role is a control (`gazereg.training.arms.gaze_controls`),
    read when asked for, so arms registered after this module was imported count too."""
    if name == "GAZE_CONTROLS":
        return gaze_controls()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def gaze_and_control(
    records: list[Record], arms: tuple[str, ...], control: str = "perturbed"
) -> list[Record]:
    """The episodes of the gaze arm and of `control`; empty when the run lacks either arm."""
    if not {"gaze", control} <= set(arms):
        return []
    return [r for r in records if run_of(r).arm in ("gaze", control)]


def _convergence_points(spec: ReportSpec, outputs: StageOutputs) -> list[ConvergencePoint]:
    """Clean success at every checkpoint, each episode with its unit (training seed, task, setup seed): the
    intermediate ones' episodes, then the final checkpoints' on the same setups (the first
    `convergence_episodes` of the final evaluation's), at the last training step."""
    last_seed = spec.eval_seed_start + min(spec.convergence_episodes, spec.eval_episodes)
    points = [
        ConvergencePoint(run_of(r), r["task"], int(r["seed"]), bool(r["success"]))
        for r in outputs.checkpoint_episodes
    ]
    points += [
        ConvergencePoint(run_of(r).at_step(spec.train_steps), r["task"], int(r["seed"]), bool(r["success"]))
        for r in outputs.episodes
        if r["condition"] == "clean" and r["seed"] < last_seed
    ]
    return points


def _training_losses(
    spec: ReportSpec, metrics_files: dict[RunId, Path]
) -> dict[str, list[tuple[int, float, float | None]]]:
    """{arm: [(step, action loss, held-out KL to its prior or None)]} of each arm's first training seed."""
    losses = {}
    for run, path in metrics_files.items():
        if run.seed == spec.train_seeds[0]:
            losses[run.arm] = [
                (r["step"], r["loss/action"], r.get("val/gaze_kl"))
                for r in read_metrics(path)
                if "loss/action" in r
            ]
    return losses
