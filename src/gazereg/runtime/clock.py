"""A wall clock that survives a killed process: the time a resumable job has spent, over all its attempts."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from types import TracebackType

from gazereg.runtime.io import atomic_write_json


class ResumableClock:
    """Context manager counting seconds into `path`, rewritten every `every` seconds while the block runs.

    A rerun after a kill starts from the seconds the file last held, so `seconds` is the job's total over
    every attempt, short of at most `every` seconds per kill. The file is left in place; whoever records
    the finished job removes it (`clear`)."""

    def __init__(self, path: str | Path, every: float = 30.0) -> None:
        if every <= 0:
            raise ValueError(f"ResumableClock: every must be > 0 seconds, got {every}")
        self.path, self.every = Path(path), every
        self.before = float(json.loads(self.path.read_text())["seconds"]) if self.path.exists() else 0.0
        self._t0: float | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def seconds(self) -> float:
        """Seconds over all attempts so far (this one still running if inside the block)."""
        return self.before + (time.perf_counter() - self._t0 if self._t0 is not None else 0.0)

    def _save(self) -> None:
        atomic_write_json(self.path, {"seconds": self.seconds})

    def _tick(self) -> None:
        while not self._stop.wait(self.every):
            self._save()

    def __enter__(self) -> ResumableClock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._t0 = time.perf_counter()
        self._save()
        self._thread = threading.Thread(target=self._tick, name=f"clock:{self.path.name}", daemon=True)
        self._thread.start()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.before, self._t0 = self.seconds, None
        self._save()

    def clear(self) -> None:
        self.path.unlink(missing_ok=True)
