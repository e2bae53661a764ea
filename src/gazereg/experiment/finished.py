"""The one reader of a finished experiment: the run folder `gazereg experiment --out` wrote, or its archive
(`gazereg archive`, e.g. docs/records/paper-abl-b), read the same way.

    run = read_run("docs/records/paper-abl-b")         # or a run folder: read_run("runs/paper-abl-b")
    run.archived                                       # True: an archive (no checkpoints, no data)
    run.config                                         # the resolved config as saved (config.json)
    run.tasks, run.env, run.arms, run.train_seeds      # typed views of it
    run.stages["train"]                                # each finished stage's record (stages/<stage>.json)
    run.runs                                           # (RunId, ...) every trained run
    run.checkpoints                                    # {RunId: final checkpoint folder, or None in an archive}
    run.episodes()                                     # the final checkpoints' evaluation records
    run.episodes_by_condition()                        # {condition: records}
    run.report                                         # report.json's content, or None
    run.metrics(RunId("gaze", 0))                      # the run's training metrics records
    run.numerics                                       # {RunId: its training attempts' numerics keys, or None}
    run.eval_config(out="runs/x", conditions=("dim:0.7",))   # its evaluation settings, to roll out again

What a folder holds (the layout this module alone reads; the stages write it):
    config.json                   the resolved `ExperimentConfig` (`runtime.config.to_dict`)
    stages/<stage>.json           each finished stage's record, its duration (`seconds`) among it
    eval/eval_info.json           the final checkpoints' evaluation (`gazereg.evaluation.rollout.evaluate`)
    converge/eval_info.json       the intermediate checkpoints' (absent when there were none)
    train/<arm>_s<seed>/          each run's folder: metrics.jsonl, checkpoints/step_NNNNNN (`run_dir`),
                                  numerics.json (`training.numerics`; absent in runs made before it)
    report.json, report.md        the report stage's output
    archive.json                  an archive's record of its source and the results' date (archives only)
An archive keeps the evaluation records and training metrics compressed (NAME.gz, read as NAME) and no
checkpoints, demonstrations or priors.

A folder is read only when it is finished: config.json and every stage but the report's; anything else is
refused with one line (UsageError). `read_stage` and `read_saved_config` read one stage record or the config
of a folder that may not be finished (a run resuming); `recorded_precision` the precision its runs trained in.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from datetime import datetime, timezone
from functools import cached_property
from pathlib import Path
from typing import Any, Literal

from gazereg.evaluation.config import EvalConfig
from gazereg.experiment.demos import demo_stores
from gazereg.report.build import StageOutputs
from gazereg.report.ids import RunId
from gazereg.runtime.errors import UsageError
from gazereg.runtime.io import exists_or_gz, read_text
from gazereg.training.logger import read_metrics
from gazereg.training.numerics import TrainingAttempt, read_numerics

STAGES = ("demos", "priors", "train", "eval", "converge", "align", "report")
"""the experiment's stages, in the order they run"""
CONFIG_FILE = "config.json"
"""the resolved configuration, at the top of a folder"""
STAGES_DIR = "stages"
"""stage records: STAGES_DIR/<stage>.json"""
EVAL_INFO = "eval_info.json"
"""an evaluation's record, in its evaluation folder (`eval`, `converge`)"""
REPORT_FILE = "report.json"
ARCHIVE_RECORD = "archive.json"
"""what an archived run folder (`gazereg.experiment.archive`) says of its source, the results' date among it"""
POOLED_RECORD = "pooled.json"
"""what `gazereg pool --out` writes beside its report: the folders pooled (no stages of its own)"""
METRICS_FILE = "metrics.jsonl"
"""a run's training metrics, in its run folder"""
EvalFolder = Literal["eval", "converge"]

Record = dict[str, Any]
"""One evaluation episode: arm (the `RunId` text, e.g. "gaze@s0" or "gaze@s0#600"), task, condition ("clean"
or a perturbation spec), seed (the setup seed), success (bool), length (steps) and, where the simulator
measures it, min_distance and final_distance (metres, object or hand to target); video (a GIF path) if
filmed."""


def stage_marker(folder: str | Path, stage: str) -> Path:
    """The record file of `stage` in the experiment folder `folder` (written when the stage finishes)."""
    return Path(folder) / STAGES_DIR / f"{stage}.json"


def read_stage(folder: str | Path, stage: str) -> dict[str, Any] | None:
    """`stage`'s record in `folder`, or None when the stage has not finished there."""
    marker = stage_marker(folder, stage)
    return json.loads(marker.read_text()) if marker.exists() else None


def read_saved_config(folder: str | Path) -> dict[str, Any] | None:
    """The configuration saved in the experiment folder `folder` (config.json as JSON), or None when it has
    none."""
    path = Path(folder) / CONFIG_FILE
    return json.loads(path.read_text()) if path.is_file() else None


def recorded_precision(folder: str | Path) -> str | None:
    """The precision ("no", "bf16", "fp16") that every training attempt of every run in the experiment
    `folder` recorded (train/*/numerics.json, `training.numerics`); None when no run recorded one, a run has
    no record or an attempt of unknown numerics, or the attempts differ."""
    run_dirs = sorted(p for p in (Path(folder) / "train").glob("*") if p.is_dir())
    attempts = [read_numerics(d) for d in run_dirs]
    if not attempts or any(a is None for a in attempts):
        return None
    keys = [t.key for a in attempts for t in a or ()]
    precisions = {k.precision for k in keys if k is not None}
    return precisions.pop() if len(precisions) == 1 and None not in keys else None


def read_report(folder: str | Path) -> dict[str, Any]:
    """The report.json of a finished experiment, its archive, or a pooled report (`gazereg pool`) in `folder`
    (`FinishedRun.report` for the first two); UsageError, one line, when `folder` has none."""
    path = Path(folder) / REPORT_FILE
    if not path.is_file():
        raise UsageError(f"{folder} has no {REPORT_FILE} (not a finished experiment or pooled report folder)")
    return json.loads(path.read_text())


def read_episodes(eval_dir: str | Path) -> list[Record]:
    """The episode records of an evaluation folder's eval_info.json (its compressed copy in an archive)."""
    return json.loads(read_text(Path(eval_dir) / EVAL_INFO))["episodes"]


def run_dir(folder: str | Path, run: RunId) -> Path:
    """The training folder of `run` (its final checkpoint: `run` without a step) in the experiment `folder`."""
    return Path(folder) / "train" / f"{run.arm}_s{run.seed}"


def results_date(folder: str | Path) -> str:
    """When the results in `folder` were produced, "YYYY-MM-DD HH:MM UTC": an archive's recorded date, else
    when the last stage before the report finished (a rerun that only rewrites the report keeps that date;
    now when none has)."""
    archived = Path(folder) / ARCHIVE_RECORD
    if archived.exists():  # its files' times are when they were copied or checked out
        return str(json.loads(archived.read_text())["date"])
    markers = [stage_marker(folder, s) for s in STAGES[:-1]]
    times = [m.stat().st_mtime for m in markers if m.exists()]
    when = datetime.fromtimestamp(max(times), timezone.utc) if times else datetime.now(timezone.utc)
    return when.strftime("%Y-%m-%d %H:%M UTC")


def read_run(path: str | Path) -> FinishedRun:
    """The finished experiment in `path` (a run folder or its archive). UsageError, one line, when `path` is
    not a folder, holds no experiment configuration, is a pooled report, or has a stage before the report
    not finished (naming the first)."""
    folder = Path(path)
    if not folder.is_dir():
        raise UsageError(f"{folder} is not a folder (a finished experiment's run folder or its archive)")
    config = read_saved_config(folder)
    if config is None:
        raise UsageError(
            f"{folder} is neither a finished experiment folder nor an archive of one (no {CONFIG_FILE})"
        )
    if (folder / POOLED_RECORD).is_file():
        raise UsageError(
            f"{folder} is a pooled report (`gazereg pool`), not one experiment: read the folders its "
            f"{POOLED_RECORD} names"
        )
    stages: dict[str, dict[str, Any]] = {}
    for stage in STAGES[:-1]:
        record = read_stage(folder, stage)
        if record is None:
            raise UsageError(f"{folder} has not finished its {stage} stage: run the experiment there first")
        stages[stage] = record
    report = read_stage(folder, STAGES[-1])
    if report is not None:
        stages[STAGES[-1]] = report
    return FinishedRun(folder, config, stages)


class FinishedRun:
    """A finished experiment, from its run folder or its archive (see the module docstring). Build it with
    `read_run`; the evaluation records and metrics are read when first asked for."""

    def __init__(self, path: Path, config: dict[str, Any], stages: dict[str, dict[str, Any]]):
        self.path = Path(path)
        self.config = config
        """the resolved configuration as saved: `runtime.config.to_dict` of its `ExperimentConfig`"""
        self.stages = stages
        """{stage: its record} for every stage before the report (and the report's, once it has run)"""
        self._episodes: dict[str, list[Record]] = {}

    def __repr__(self) -> str:
        return f"FinishedRun({str(self.path)!r}, archived={self.archived})"

    # ----- the configuration ------------------------------------------------------------------------------
    @property
    def archived(self) -> bool:
        """An archive (`gazereg archive`): records only, no checkpoints, demonstrations or priors."""
        return (self.path / ARCHIVE_RECORD).is_file()

    @property
    def env(self) -> str:
        """the simulator's registered name"""
        return str(self.config["env"])

    @property
    def tasks(self) -> tuple[str, ...]:
        return tuple(self.config["tasks"])

    @property
    def arms(self) -> tuple[str, ...]:
        return tuple(self.config["arms"])

    @property
    def train_seeds(self) -> tuple[int, ...]:
        return tuple(int(s) for s in self.config["train_seeds"])

    @property
    def camera(self) -> str:
        """the camera the gaze priors and attention maps are on"""
        return str(self.config["camera"])

    @property
    def train_steps(self) -> int:
        """training steps of every run"""
        return int(self.config["train"]["steps"])

    @property
    def gaze_layers(self) -> tuple[int, ...]:
        """the policy layers whose attention the gaze term reads (negative: from the last)"""
        return tuple(int(layer) for layer in self.config["train"]["gaze"]["layers"])

    @property
    def max_steps(self) -> int:
        """the evaluation's step limit per episode"""
        return int(self.config["eval"]["max_steps"])

    def eval_config(
        self, out: str | Path, checkpoints: Mapping[RunId, str | Path] | None = None, **changes: Any
    ) -> EvalConfig:
        """The experiment's evaluation settings (its tasks, simulator, setups, step limit, workers, batch ...)
        as an `EvalConfig` writing into `out`, evaluating `checkpoints` (default: the final ones; UsageError
        in an archive, which has none), with `changes` to its fields."""
        if checkpoints is None:
            checkpoints = self.final_checkpoints()
        names = {f.name for f in dataclasses.fields(EvalConfig)}
        saved = {
            k: tuple(v) if isinstance(v, list) else v for k, v in self.config["eval"].items() if k in names
        }
        return EvalConfig(
            **{
                **saved,
                "env": self.env,
                "tasks": self.tasks,
                "checkpoints": tuple(f"{run}={path}" for run, path in checkpoints.items()),
                "out": Path(out),
                **changes,
            }
        )

    # ----- runs and checkpoints ---------------------------------------------------------------------------
    @property
    def runs(self) -> tuple[RunId, ...]:
        """every trained run (arm x training seed), as the train stage recorded them"""
        return tuple(RunId.parse(name) for name in self.stages["train"]["runs"])

    @property
    def checkpoints(self) -> dict[RunId, Path | None]:
        """{run: its final checkpoint folder}, None for every run of an archive. A checkpoint is looked for in
        this folder's own train/<run>/checkpoints first (the folder may have moved since it ran), else at the
        path the train stage recorded."""
        out: dict[RunId, Path | None] = {}
        for name, record in self.stages["train"]["runs"].items():
            run = RunId.parse(name)
            if self.archived:
                out[run] = None
                continue
            recorded = Path(record["checkpoint"])
            here = run_dir(self.path, run) / "checkpoints" / recorded.name
            out[run] = here if here.is_dir() else recorded
        return out

    def final_checkpoints(self) -> dict[RunId, Path]:
        """`checkpoints`, refused (UsageError) in an archive: for what must load the policies."""
        if self.archived:
            raise UsageError(
                f"{self.path} is an archive (`gazereg archive`): it keeps no checkpoints to load; "
                "give the run folder it was made from"
            )
        return {run: path for run, path in self.checkpoints.items() if path is not None}

    @property
    def final_metrics(self) -> dict[RunId, dict[str, float]]:
        """{run: its metrics at its last training step} (empty for a run resumed past its last step)"""
        runs = self.stages["train"]["runs"]
        return {RunId.parse(name): r.get("final_metrics", {}) for name, r in runs.items()}

    def metrics_file(self, run: RunId) -> Path:
        """`run`'s metrics.jsonl (in an archive only its .gz exists; `runtime.io.read_text` reads either)."""
        return run_dir(self.path, run) / METRICS_FILE

    def metrics(self, run: RunId) -> list[dict[str, Any]]:
        """`run`'s training metrics, one record per logged step (`training.logger.read_metrics`: step, loss,
        loss/action, loss/gaze_kl, lr, ...; [] when it logged none)."""
        return read_metrics(self.metrics_file(run))

    @cached_property
    def numerics(self) -> dict[RunId, tuple[TrainingAttempt, ...] | None]:
        """{run: the numerics keys its training attempts recorded (`training.numerics`: one attempt per machine
        and resume, in order)}, None for a run that recorded none (trained before runs recorded their key)"""
        return {run: read_numerics(run_dir(self.path, run)) for run in self.runs}

    # ----- evaluation records -----------------------------------------------------------------------------
    def episodes(self, folder: EvalFolder = "eval") -> list[Record]:
        """The evaluation records (`Record`) of `folder`: "eval", the final checkpoints under every condition;
        "converge", the intermediate checkpoints, clean (their runs name their step; [] when there were
        none)."""
        if folder not in self._episodes:
            if folder == "converge" and not exists_or_gz(self.path / folder / EVAL_INFO):
                if self.stages["converge"].get("eval_info") is not None:
                    raise UsageError(f"{self.path}: converge/{EVAL_INFO} is missing, though its stage ran")
                self._episodes[folder] = []
            else:
                self._episodes[folder] = read_episodes(self.path / folder)
        return self._episodes[folder]

    def episodes_by_condition(self, folder: EvalFolder = "eval") -> dict[str, list[Record]]:
        """{condition: its records in `folder`}, conditions in the order they first appear."""
        out: dict[str, list[Record]] = {}
        for record in self.episodes(folder):
            out.setdefault(record["condition"], []).append(record)
        return out

    # ----- the report and what it is built from -----------------------------------------------------------
    @cached_property
    def report(self) -> dict[str, Any] | None:
        """report.json's content (success, paired tests, convergence, stage times ...), or None before the
        report stage has run."""
        path = self.path / REPORT_FILE
        return json.loads(path.read_text()) if path.is_file() else None

    @property
    def stage_times(self) -> dict[str, float]:
        """{stage: seconds} for every stage before the report (every attempt at it summed)"""
        return {stage: float(self.stages[stage].get("seconds", 0.0)) for stage in STAGES[:-1]}

    @property
    def date(self) -> str:
        """when the results were produced (`results_date`)"""
        return results_date(self.path)

    def stage_outputs(self) -> StageOutputs:
        """What the finished stages produced, as the report reads it."""
        return StageOutputs(
            episodes=self.episodes("eval"),
            checkpoint_episodes=self.episodes("converge"),
            demos=self.stages["demos"]["train"],
            glc=self.stages["priors"].get("glc"),
            final_metrics=self.final_metrics,
            metrics_files={run: self.metrics_file(run) for run in self.runs},
            alignment={RunId.parse(n): v for n, v in self.stages["align"]["alignment"].items()},
            attention_figure=self.stages["align"]["figure"],
            date=self.date,
            stage_times=self.stage_times,
            numerics=self.numerics,
        )

    # ----- data a run folder keeps beside its results -----------------------------------------------------
    def collect_config(self, store: str = "heldout") -> dict[str, Any]:
        """The settings the episode store `store` (`demos.demo_stores`: "train", "heldout", "glc") was collected with (its
        collect/config.json: tasks, setups, camera, image size, steps); UsageError in an archive."""
        if self.archived:
            raise UsageError(f"{self.path} is an archive (`gazereg archive`): it keeps no demonstrations")
        stores = demo_stores(self.path)
        if store not in stores:
            raise ValueError(f"no episode store {store!r}: one of {', '.join(stores)}")
        folder = stores[store]
        saved = read_saved_config(folder / "collect")
        if saved is None:
            raise UsageError(f"{folder} holds no collection (no collect/{CONFIG_FILE})")
        return saved
