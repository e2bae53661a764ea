"""A finished pretraining's results block (`gazereg pretrain`; docs/pretraining.md), rendered from
plain data: its manifest.json, its stages' wall times, its evaluation episodes and its training metrics rows,
as `gazereg.experiment.read_pretraining` reads them from the folder or its archive. Nothing here reads files.

    pretrain_block(run.manifest, run.stage_times, run.episodes, run.metrics, run.date)

The block: the run line (date, software and commit, wall time per stage, the command, the numerics), the
policy (parameters, weights' SHA-256 prefix, the fine-tuning options), the demonstrations (episodes, frames,
fingerprint), the multi-task success pooled over every episode with its Wilson 95% interval, a per-task table
(task, its instruction, k/n, Wilson 95%) sorted by task name, the training's final action loss, and last the
data line (`blockdata.BlockData`: the numerics key and the success count {arm: {condition: [k, n]}}) that
scripts/update_results.py --check compares. The success counts are recounted from the episodes, never taken
from the manifest's summary.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from gazereg.envs.metaworld.instructions import instruction_for
from gazereg.evaluation.stats import wilson
from gazereg.report.blockdata import BlockData
from gazereg.report.sections import numerics_text
from gazereg.runtime.hardware import NumericsKey

SHA_PREFIX = 16
"""hex digits of the policy weights' SHA-256 shown"""
SOFTWARE = ("gazereg", "torch", "metaworld", "mujoco")
"""the versions the run line names, where the manifest records them"""


def success_counts(episodes: Sequence[Mapping[str, Any]]) -> tuple[str, str, dict[str, tuple[int, int]]]:
    """(arm, condition, {task: (successes, episodes)}) of a pretraining's evaluation episodes, tasks sorted by
    name. ValueError when the episodes are none or hold more than one arm x condition (a pretraining
    evaluates one policy, clean)."""
    cells = sorted({(str(e["arm"]), str(e["condition"])) for e in episodes})
    if len(cells) != 1:
        raise ValueError(
            f"a pretraining's evaluation holds one arm x condition; these episodes hold {len(cells)}: {cells}"
        )
    per_task: dict[str, list[int]] = {}
    for e in episodes:
        kn = per_task.setdefault(str(e["task"]), [0, 0])
        kn[0] += bool(e["success"])
        kn[1] += 1
    arm, condition = cells[0]
    return arm, condition, {task: (kn[0], kn[1]) for task, kn in sorted(per_task.items())}


def _interval(k: int, n: int) -> str:
    lo, hi = wilson(k, n)
    return f"[{lo:.2f}, {hi:.2f}]"


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:.1f}"


def run_line(manifest: Mapping[str, Any], stage_seconds: Mapping[str, float], date: str) -> str:
    """When, with what software at which commit, how long (per stage, minutes), the command, the numerics."""
    git = manifest.get("git") or {}
    commit = f"commit {str(git['commit'])[:10]}" if git.get("commit") else "no git commit recorded"
    if git.get("dirty"):
        commit += " with uncommitted changes"
    versions = manifest.get("versions") or {}
    software = ", ".join(f"{name} {versions[name]}" for name in SOFTWARE if name in versions)
    total = sum(stage_seconds.values())
    stages = ", ".join(f"{stage} {_minutes(s)}" for stage, s in stage_seconds.items())
    numerics = numerics_text({"numerics": manifest.get("numerics")})
    return (
        f"Latest `{manifest['preset']}` pretraining: {date}, {software} at {commit}; wall time "
        f"{_minutes(total)} min ({stages} min) (`{' '.join(manifest['command'])}`); {numerics}."
    )


def policy_line(manifest: Mapping[str, Any]) -> str:
    """The policy's size, its weights' SHA-256 prefix and the options giving a fine-tuning run its shape."""
    policy = manifest["policy"]
    flags = " ".join(["--train.init-from", "POLICY_FOLDER", *policy["finetune_flags"]])
    sha = str(policy["model_sha256"])[:SHA_PREFIX]
    return (
        f"Policy: {int(policy['parameters_and_buffers']):,} parameters and buffers, model.safetensors "
        f"SHA-256 `{sha}`; fine-tune with `{flags}`."
    )


def data_line(manifest: Mapping[str, Any]) -> str:
    """The demonstrations: episodes, frames, their setups and fingerprint."""
    data = manifest["data"]
    seeds = data.get("setup_seeds")
    where = f" on setups from seed {seeds[0]}" if seeds else ""
    return (
        f"Demonstrations: {data['episodes']} episodes ({data['frames']} frames) by Meta-World's scripted "
        f"experts{where}; fingerprint `{data['fingerprint']}`."
    )


def loss_line(metrics: Sequence[Mapping[str, Any]], steps: int | None) -> str:
    """The training's last logged action loss (and validation loss where logged with it)."""
    rows = [r for r in metrics if "loss/action" in r]
    if not rows:
        return "Training: no action loss was logged."
    last = rows[-1]
    val = f" (validation {float(last['val/loss_action']):.4f})" if "val/loss_action" in last else ""
    of = f" of {steps}" if steps is not None else ""
    return f"Training: final action loss {float(last['loss/action']):.4f}{val} at step {last['step']}{of}."


def success_lines(episodes: Sequence[Mapping[str, Any]]) -> list[str]:
    """The pooled success with its Wilson 95% interval, then one row per task (sorted by name)."""
    _, condition, per_task = success_counts(episodes)
    k, n = sum(kn[0] for kn in per_task.values()), sum(kn[1] for kn in per_task.values())
    first = min(int(e["seed"]) for e in episodes)
    return [
        f"Multi-task success ({condition}, {n} episodes over {len(per_task)} tasks, unseen setups from seed "
        f"{first}): **{k}/{n} = {k / n:.2f}** {_interval(k, n)} (Wilson 95%).",
        "",
        "| task | instruction | success | Wilson 95% |",
        "|---|---|---|---|",
        *[
            f"| {task} | {instruction_for(task)} | {tk}/{tn} | {_interval(tk, tn)} |"
            for task, (tk, tn) in per_task.items()
        ],
    ]


def block_data(manifest: Mapping[str, Any], episodes: Sequence[Mapping[str, Any]]) -> BlockData:
    """The block's data: the manifest's numerics key and the pooled success count {arm: {condition: (k, n)}},
    recounted from the episodes."""
    arm, condition, per_task = success_counts(episodes)
    pooled = (sum(kn[0] for kn in per_task.values()), sum(kn[1] for kn in per_task.values()))
    key = manifest.get("numerics")
    return BlockData(numerics=NumericsKey.from_dict(key) if key else None, success={arm: {condition: pooled}})


def pretrain_block(
    manifest: Mapping[str, Any],
    stage_seconds: Mapping[str, float],
    episodes: Sequence[Mapping[str, Any]],
    metrics: Sequence[Mapping[str, Any]],
    date: str,
) -> str:
    """The pretraining's results block (module docstring): `manifest` is manifest.json's content,
    `stage_seconds` {stage: wall seconds} in the order the stages ran, `episodes` the evaluation records,
    `metrics` the training's metrics rows, `date` when the results were produced. Its first line is the run
    line (what changes from run to run); ends with the data line and a newline."""
    steps = (manifest.get("config") or {}).get("train", {}).get("steps")
    lines = [
        run_line(manifest, stage_seconds, date),
        "",
        policy_line(manifest),
        data_line(manifest),
        "",
        *success_lines(episodes),
        "",
        loss_line(metrics, steps),
        block_data(manifest, episodes).line(),
        "",
    ]
    return "\n".join(lines)
