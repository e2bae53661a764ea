"""Wall-clock timing and the machine description shared by the benchmark scripts (imported as `_timing`:
scripts run from this folder)."""

from __future__ import annotations

import os
import platform
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from gazereg.runtime.hardware import BF16_CPU_FLAGS, cpu_flags, native_bf16


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


def machine_info(**extra: Any) -> dict[str, Any]:
    """Platform, CPU model, cores this process may use, torch and its threads, the bf16 CPU flags, the load
    average now (other jobs slow a benchmark down), and `extra`."""
    info = Path("/proc/cpuinfo")
    lines = info.read_text().splitlines() if info.exists() else []
    models = [ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("model name")]
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_model": models[0] if models else None,
        "cores": len(os.sched_getaffinity(0)),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "cpu_flags": {f: f in cpu_flags() for f in sorted(BF16_CPU_FLAGS)},
        "native_bf16_cpu": native_bf16("cpu"),
        "load_avg_before": [round(x, 2) for x in os.getloadavg()],
        **extra,
    }
