"""The one reader of a finished pretraining: the folder `gazereg pretrain --out` wrote, or its archive
(`gazereg archive`, e.g. docs/records/pretrain-ml45), read the same way.

    run = read_pretraining("docs/records/pretrain-ml45")   # or the folder: read_pretraining("runs/pretrain")
    run.archived                  # True: an archive (no demonstrations, checkpoints or policy weights)
    run.manifest                  # manifest.json: command, git, data, policy, numerics, evaluation, versions
    run.config                    # the resolved `PretrainConfig` as saved (config.json)
    run.stages["eval"]            # each stage's record (stages/<stage>.json), its `seconds` among it
    run.episodes                  # every evaluation episode (task, seed, success, length, distances)
    run.metrics                   # the training's metrics rows (step, loss, loss/action, lr, ...)
    run.date                      # when the results were produced, "YYYY-MM-DD HH:MM UTC"

What a folder holds (`gazereg.experiment.pretrain` writes it; this module alone reads it back):
    config.json                   the resolved `PretrainConfig` (`runtime.config.to_dict`)
    manifest.json                 the manifest stage's record of the whole run
    stages/<stage>.json           each finished stage's record (demos, train, eval, manifest)
    eval/eval_info.json           the policy's evaluation (`gazereg.evaluation.rollout.evaluate`)
    train/metrics.jsonl           the training's metrics (train/checkpoints beside it)
    policy/, demos/               the weights to fine-tune from, the demonstrations (never archived)
    archive.json                  an archive's record of its source and the results' date (archives only)
An archive may keep eval_info.json and keeps metrics.jsonl compressed (NAME.gz, read as NAME).

A folder is read only when every stage has finished, the manifest's last; anything else is refused with one
line (UsageError) naming the first unfinished stage.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from gazereg.experiment.finished import (
    ARCHIVE_RECORD,
    CONFIG_FILE,
    METRICS_FILE,
    STAGES_DIR,
    Record,
    read_episodes,
    read_saved_config,
    read_stage,
    stage_marker,
)
from gazereg.experiment.pretrain import STAGES
from gazereg.experiment.pretrain_config import PretrainConfig
from gazereg.report.pretrain import pretrain_block
from gazereg.runtime.errors import UsageError
from gazereg.training.logger import read_metrics

MANIFEST_FILE = "manifest.json"
"""the manifest stage's record of the run, at the top of a folder"""
EVAL_DIR = "eval"
TRAIN_DIR = "train"
"""the training's folder: METRICS_FILE and its checkpoints"""
PRETRAIN_KEYS = frozenset(f.name for f in dataclasses.fields(PretrainConfig))
"""the keys of a saved pretraining configuration"""


def is_pretraining(path: str | Path) -> bool:
    """Whether `path` is a pretraining folder or its archive, finished or not: it has a manifest stage record,
    or its saved configuration's keys are `PretrainConfig`'s (an experiment's has keys of its own, e.g.
    "arms")."""
    folder = Path(path)
    if stage_marker(folder, STAGES[-1]).is_file():
        return True
    config = read_saved_config(folder) if folder.is_dir() else None
    return bool(config) and set(config) <= PRETRAIN_KEYS


def pretraining_date(folder: str | Path) -> str:
    """When the results in `folder` were produced, "YYYY-MM-DD HH:MM UTC": an archive's recorded date, else
    when its last stage record was written (now when none was)."""
    archived = Path(folder) / ARCHIVE_RECORD
    if archived.is_file():  # its files' times are when they were copied or checked out
        return str(json.loads(archived.read_text())["date"])
    times = [m.stat().st_mtime for m in (stage_marker(folder, s) for s in STAGES) if m.exists()]
    when = datetime.fromtimestamp(max(times), timezone.utc) if times else datetime.now(timezone.utc)
    return when.strftime("%Y-%m-%d %H:%M UTC")


@dataclass(frozen=True)
class FinishedPretraining:
    """A finished pretraining, from its folder or its archive (module docstring). Build it with
    `read_pretraining`; everything is read when it is built."""

    path: Path
    archived: bool
    """an archive (`gazereg archive`): records only"""
    date: str
    """when the results were produced (`pretraining_date`)"""
    config: dict[str, Any]
    """the resolved configuration as saved: `runtime.config.to_dict` of its `PretrainConfig`"""
    manifest: dict[str, Any]
    """manifest.json: command, git, data, policy, numerics, evaluation summary, stage_seconds, versions"""
    stages: dict[str, dict[str, Any]]
    """{stage: its record} for every stage, in the order they ran"""
    episodes: tuple[Record, ...]
    """every evaluation episode: arm ("pretrained"), task, condition ("clean"), seed, success, length (steps),
    min_distance and final_distance (metres)"""
    metrics: tuple[dict[str, Any], ...]
    """the training's metrics, one row per logged step (step, loss, loss/action, val/loss_action, lr, ...)"""

    @property
    def tasks(self) -> tuple[str, ...]:
        return tuple(self.config["tasks"])

    @property
    def stage_times(self) -> dict[str, float]:
        """{stage: seconds} for every stage (every attempt at it summed)"""
        return {stage: float(record.get("seconds", 0.0)) for stage, record in self.stages.items()}

    def block(self) -> str:
        """The results block of a docs page (`gazereg.report.pretrain.pretrain_block`), ending with its data
        line."""
        return pretrain_block(self.manifest, self.stage_times, self.episodes, self.metrics, self.date)

    @property
    def metrics_file(self) -> Path:
        """train/metrics.jsonl (in an archive only its .gz exists; `runtime.io.read_text` reads either)"""
        return self.path / TRAIN_DIR / METRICS_FILE


def read_pretraining(path: str | Path) -> FinishedPretraining:
    """The finished pretraining in `path` (its folder or its archive). UsageError, one line, when `path` is
    not a folder, holds no pretraining configuration or manifest, or has a stage not finished (naming the
    first)."""
    folder = Path(path)
    if not folder.is_dir():
        raise UsageError(f"{folder} is not a folder (a finished pretraining folder or its archive)")
    config = read_saved_config(folder)
    if config is None or not is_pretraining(folder):
        why = f"no {CONFIG_FILE}" if config is None else f"its {CONFIG_FILE} is not a pretraining's"
        raise UsageError(
            f"{folder} is neither a pretraining folder (`gazereg pretrain --out`) nor an archive of one ({why})"
        )
    stages: dict[str, dict[str, Any]] = {}
    for stage in STAGES:
        record = read_stage(folder, stage)
        if record is None:
            raise UsageError(
                f"{folder} has not finished its {stage} stage ({STAGES_DIR}/{stage}.json): rerun its "
                "`gazereg pretrain` command there first"
            )
        stages[stage] = record
    manifest = folder / MANIFEST_FILE
    if not manifest.is_file():
        raise UsageError(f"{folder} has no {MANIFEST_FILE} though its manifest stage finished")
    return FinishedPretraining(
        path=folder,
        archived=(folder / ARCHIVE_RECORD).is_file(),
        date=pretraining_date(folder),
        config=config,
        manifest=json.loads(manifest.read_text()),
        stages=stages,
        episodes=tuple(read_episodes(folder / EVAL_DIR)),
        metrics=tuple(read_metrics(folder / TRAIN_DIR / METRICS_FILE)),
    )
