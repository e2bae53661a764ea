"""Finished runs of one experiment read as one: a benchmark run in sittings (`gazereg sittings`), each sitting
its own folder or archive, or a pooled report (`gazereg pool`) through the folders its pooled.json names.

    run = pooled_runs([read_run("docs/records/libero-spatial-s0"), read_run("docs/records/libero-spatial-s0-glc")])
    run = read_results("runs/libero-spatial")     # a pooled report: its folders' runs; else `read_run`
    run.env, run.tasks, run.train_seeds, run.episodes()

Every folder must be a run of the same simulator and tasks, and no run (arm x training seed) may come from two
folders; the episodes are the folders' final evaluation records together (each run's from the folder that
trained it). What the pooled report itself checks (the same configuration, demonstrations and GLC):
`gazereg.experiment.pool`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gazereg.experiment.finished import POOLED_RECORD, FinishedRun, read_run
from gazereg.runtime.errors import UsageError


@dataclass(frozen=True)
class PooledRuns:
    """Several finished runs of one experiment as one (`pooled_runs`): what a report of their episodes reads."""

    path: Path
    """the pooled report's folder, or the first part's when the parts were given one by one"""
    parts: tuple[FinishedRun, ...]
    """the finished experiments (folders or archives) pooled, in order"""

    @property
    def env(self) -> str:
        return self.parts[0].env

    @property
    def tasks(self) -> tuple[str, ...]:
        return self.parts[0].tasks

    @property
    def train_seeds(self) -> tuple[int, ...]:
        return tuple(sorted({s for run in self.parts for s in run.train_seeds}))

    def episodes(self) -> list[dict[str, Any]]:
        """Every part's final evaluation records, the parts in order."""
        return [ep for run in self.parts for ep in run.episodes()]


def pooled_runs(runs: Sequence[FinishedRun | PooledRuns], path: Path | None = None) -> PooledRuns:
    """`runs` (a pooled one stands for its parts) as one; UsageError, one line, for none, a run of another
    simulator or tasks than the first, or a run (arm x seed) that two folders trained."""
    flat = [p for r in runs for p in (r.parts if isinstance(r, PooledRuns) else (r,))]
    if not flat:
        raise UsageError("no runs to pool")
    first, seen = flat[0], {}
    for run in flat:
        if run.env != first.env or run.tasks != first.tasks:
            raise UsageError(
                f"{run.path}: a {run.env} run of {', '.join(run.tasks)}, not one experiment with {first.path} "
                f"({first.env}, {', '.join(first.tasks)})"
            )
        for rid in run.runs:
            if rid in seen:
                raise UsageError(
                    f"{rid} is in both {seen[rid]} and {run.path}: pool each run from one folder"
                )
            seen[rid] = run.path
    return PooledRuns(Path(path) if path is not None else first.path, tuple(flat))


def read_pooled(folder: str | Path) -> PooledRuns:
    """The pooled report in `folder` as its folders' runs (their paths as pooled.json names them: relative to
    the directory `gazereg pool` ran in, the repository root). UsageError when `folder` is no pooled report."""
    record = Path(folder) / POOLED_RECORD
    if not record.is_file():
        raise UsageError(f"{folder} has no {POOLED_RECORD} (not a pooled report folder)")
    folders = json.loads(record.read_text())["folders"]
    return pooled_runs([read_run(f) for f in folders], Path(folder))


def read_results(folder: str | Path) -> FinishedRun | PooledRuns:
    """A finished experiment (`read_run`), its archive, or a pooled report (`read_pooled`) in `folder`."""
    return read_pooled(folder) if (Path(folder) / POOLED_RECORD).is_file() else read_run(folder)
