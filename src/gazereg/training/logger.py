"""Metric sinks: metrics.jsonl (always, the run's record) plus an optional external logger.

The external logger is a no-op by default; `tensorboard` and `wandb` are imported only when chosen.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from gazereg.runtime.io import append_jsonl, atomic_write_text


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
        """Drop records beyond `step` (a resumed run rewrites what came after its checkpoint)."""
        if not self.path.exists():
            return
        keep = [
            line
            for line in self.path.read_text().splitlines()
            if line.strip() and json.loads(line).get("step", 0) <= step
        ]
        atomic_write_text(self.path, "".join(line + "\n" for line in keep))


def read_metrics(path: str | Path) -> list[dict[str, Any]]:
    p = Path(path)
    return [json.loads(line) for line in p.read_text().splitlines() if line.strip()] if p.exists() else []
