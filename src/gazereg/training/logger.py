"""Metric sinks: metrics.jsonl (always, the run's record) plus an optional external logger.

The external logger is a no-op by default; `tensorboard` and `wandb` are imported only when chosen.
A killed run can leave a partial last line in metrics.jsonl: readers skip it (with a logged warning) and a
resumed run drops it; a line that does not parse anywhere else raises ValueError naming the file and line.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import Any

from gazereg.runtime.io import append_jsonl, atomic_write_text, exists_or_gz, read_text

log = logging.getLogger(__name__)


class NullLogger:
    def log(self, metrics: dict[str, Any], step: int) -> None:
        pass

    def close(self) -> None:
        pass


class TensorBoardLogger(NullLogger):
    def __init__(self, run_dir: Path):
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError as e:  # pragma: no cover - optional dependency
            raise ImportError(
                "logger=tensorboard needs the tensorboard package: pip install tensorboard"
            ) from e
        self.writer = SummaryWriter(str(run_dir / "tensorboard"))

    def log(self, metrics: dict[str, Any], step: int) -> None:
        for k, v in metrics.items():
            if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v):
                self.writer.add_scalar(k, v, step)

    def close(self) -> None:
        self.writer.close()


class WandbLogger(NullLogger):
    def __init__(self, run_dir: Path, config: dict[str, Any], project: str, mode: str):
        try:
            import wandb
        except ImportError as e:  # pragma: no cover - optional dependency
            raise ImportError("logger=wandb needs the wandb package: pip install wandb") from e
        self.run = wandb.init(project=project, dir=str(run_dir), config=config, mode=mode, name=run_dir.name)

    def log(self, metrics: dict[str, Any], step: int) -> None:
        self.run.log({k: v for k, v in metrics.items() if isinstance(v, int | float)}, step=step)

    def close(self) -> None:
        self.run.finish()


def make_logger(
    kind: str, run_dir: Path, config: dict[str, Any], project: str = "gazereg", wandb_mode: str = "offline"
) -> NullLogger:
    if kind == "none":
        return NullLogger()
    if kind == "tensorboard":
        return TensorBoardLogger(run_dir)
    if kind == "wandb":
        return WandbLogger(run_dir, config, project, wandb_mode)
    raise ValueError(f"unknown logger {kind!r}; use none, tensorboard or wandb")


class MetricsFile:
    """run_dir/metrics.jsonl: one JSON object per logged step (flushed line by line)."""

    def __init__(self, path: Path):
        self.path = path

    def write(self, record: dict[str, Any]) -> None:
        append_jsonl(
            self.path,
            {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in record.items()},
        )

    def truncate_after(self, step: int) -> None:
        """Keep only the records up to `step` (a resumed run rewrites what came after its checkpoint; a run
        started from scratch, step 0, starts an empty file) and drop a partial last line."""
        if not self.path.exists():
            return
        keep = [line for line, record in _records(self.path) if record.get("step", 0) <= step]
        atomic_write_text(self.path, "".join(line + "\n" for line in keep))


def read_metrics(path: str | Path) -> list[dict[str, Any]]:
    """The records of a metrics.jsonl, or of its compressed copy in an archived run folder ([] when neither
    exists). A last line that does not parse (a write cut short by a kill) is skipped with a warning; any other
    bad line raises ValueError naming path:line."""
    p = Path(path)
    return [record for _, record in _records(p)] if exists_or_gz(p) else []


def _records(p: Path) -> list[tuple[str, dict[str, Any]]]:
    """(line, record) for every record line of an existing metrics file (see `read_metrics`)."""
    lines = read_text(p).splitlines()
    last = max((i for i, line in enumerate(lines) if line.strip()), default=-1)
    records = []
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
            if not isinstance(record, dict):
                raise ValueError(f"a JSON {type(record).__name__}, not an object")
        except ValueError as e:
            if i == last:
                log.warning("%s:%d: skipping a partial last line (%s)", p, i + 1, e)
                continue
            raise ValueError(f"{p}:{i + 1} is not a metrics record ({e})") from e
        records.append((line, record))
    return records
