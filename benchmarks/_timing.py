"""Wall-clock timing shared by the benchmark scripts (imported as `_timing`: scripts run from this folder)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable


def run_times(fn: Callable[[], object], repeat: int, warmup: int = 1) -> list[float]:
    """Seconds per call of `fn` over `repeat` timed calls, after `warmup` untimed ones."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def median_time(fn: Callable[[], object], repeat: int, warmup: int = 1) -> float:
    """Median seconds per call (see run_times)."""
    return statistics.median(run_times(fn, repeat, warmup))
