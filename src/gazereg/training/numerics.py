"""The numerics key a training run recorded when it trained (numerics.json in its run folder): which machine
and precision computed its numbers, for reports built later, elsewhere, or pooled over sittings.

    attempts = record_numerics(run_dir, "no", start=0)   # at the start of training (main process)
    read_numerics(run_dir)                               # (TrainingAttempt, ...) or None: made before the file

The file holds one entry per attempt at training the run (a start from scratch, then each resume that
trained a step): {"attempts": [{"attempt": 1, "start_step": 0, "key": NumericsKey.to_dict(), "cpu_model":
"..."}, ...]}, so a run trained across machines shows every machine's key, never only the last one's. A start
from scratch (step 0) replaces the file, as it empties metrics.jsonl: nothing of an earlier attempt that
saved no checkpoint survives in the run. A resume of a run that trained before runs recorded their key
records that first part as an attempt whose key is None (unknown). A resume on a machine whose key differs
from the earlier attempts' is logged as a warning. The file is written atomically.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gazereg.runtime import hardware
from gazereg.runtime.errors import UsageError
from gazereg.runtime.hardware import NumericsKey
from gazereg.runtime.io import atomic_write_json

log = logging.getLogger(__name__)

NUMERICS_FILE = "numerics.json"
"""the run's recorded numerics keys, in its run folder"""


@dataclass(frozen=True)
class TrainingAttempt:
    """One attempt at training a run: its number (1, 2, ...), the first step it trained, the `NumericsKey` of
    the machine and precision it trained with (None: not recorded, a part trained before runs recorded
    their key) and the CPU's model name (None where unknown)."""

    attempt: int
    start_step: int
    key: NumericsKey | None
    cpu_model: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "attempt": self.attempt,
            "start_step": self.start_step,
            "key": self.key.to_dict() if self.key is not None else None,
            "cpu_model": self.cpu_model,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainingAttempt:
        """The inverse of to_dict; KeyError or TypeError for a malformed entry."""
        return cls(
            attempt=int(d["attempt"]),
            start_step=int(d["start_step"]),
            key=NumericsKey.from_dict(d["key"]) if d["key"] is not None else None,
            cpu_model=None if d["cpu_model"] is None else str(d["cpu_model"]),
        )


def read_numerics(run_dir: str | Path) -> tuple[TrainingAttempt, ...] | None:
    """The attempts recorded in `run_dir`'s numerics.json, in order; None when it has none (a run trained
    before runs recorded their key, or an archive of one). UsageError naming the file when it does not read."""
    path = Path(run_dir) / NUMERICS_FILE
    if not path.is_file():
        return None
    try:
        return tuple(TrainingAttempt.from_dict(a) for a in json.loads(path.read_text())["attempts"])
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
        raise UsageError(f"{path} is not a numerics record ({e!r}): delete it or restore it") from e


def record_numerics(run_dir: str | Path, precision: str, start: int) -> tuple[TrainingAttempt, ...]:
    """Record this machine's key for training in `precision` (resolved: "no", "bf16", "fp16") from step
    `start` in `run_dir`'s numerics.json; returns every attempt recorded. `start` 0 replaces the file; a
    resume appends to it (after an attempt with key None from step 0 when the run has no file yet)."""
    earlier = read_numerics(run_dir) if start > 0 else None
    if start > 0 and earlier is None:
        earlier = (TrainingAttempt(1, 0, None),)
    key = NumericsKey.here(precision)
    attempts = (
        *(earlier or ()),
        TrainingAttempt(len(earlier or ()) + 1, start, key, hardware.cpu_identity()[1]),
    )
    atomic_write_json(Path(run_dir) / NUMERICS_FILE, {"attempts": [a.to_dict() for a in attempts]})
    before = {a.key for a in earlier or () if a.key is not None}
    if before and key not in before:
        said = "; ".join(d for k in before for d in k.differences(key))
        log.warning(
            "%s: resumed on a machine whose numerics differ from the earlier attempts' (%s; earlier vs "
            "now): its report will say it trained on several machines",
            run_dir,
            said,
        )
    return attempts
