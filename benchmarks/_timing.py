"""Wall-clock timing and the machine description shared by the benchmark scripts (imported as `_timing`:
scripts run from this folder)."""

from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from gazereg.runtime.hardware import (
    BF16_CPU_FLAGS,
    NumericsKey,
    auto_precision,
    cpu_flags,
    cpu_identity,
    native_bf16,
)


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


def machine_info(precision: str | None = None, **extra: Any) -> dict[str, Any]:
    """Platform, CPU vendor and model, cores this process may use, torch and its threads, torch's CPU
    capability (the kernels it dispatches to: "AVX2", "AVX512", ...), the bf16 CPU flags, the precision the
    benchmark trains or infers in (`precision`, resolved: "no" = float32, "bf16"; default: what
    `--train.mixed_precision auto` resolves to here) and the resulting `NumericsKey`, the load average now
    (other jobs slow a benchmark down), and `extra`."""
    resolved = precision if precision is not None else auto_precision("cpu")
    vendor, model = cpu_identity()
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_vendor": vendor,
        "cpu_model": model,
        "cores": len(os.sched_getaffinity(0)),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "cpu_flags": {f: f in cpu_flags() for f in sorted(BF16_CPU_FLAGS)},
        "native_bf16_cpu": native_bf16("cpu"),
        "resolved_precision": resolved,
        "numerics": NumericsKey.here(resolved).to_dict(),
        "load_avg_before": [round(x, 2) for x in os.getloadavg()],
        **extra,
    }


def machine_line(m: dict[str, Any]) -> str:
    """`machine_info`'s record as the head of a benchmark's table: CPU, cores, torch, training precision and
    the load average before the run."""
    precision = "bf16" if m["resolved_precision"] == "bf16" else "float32"
    return (
        f"{m['cpu_model']} ({m['cpu_vendor']}, torch CPU capability {m['cpu_capability']}), {m['cores']} cores, "
        f"torch {m['torch']}, {precision}; load average before {m['load_avg_before'][0]}"
    )


def print_markdown(path: Path, render: Callable[[dict[str, Any], str], str], prog: str) -> int:
    """`--markdown JSON` of a benchmark script: print `render(the JSON, its file name)` and return 0, or one line
    on stderr naming the missing file and return 2."""
    if not path.is_file():
        print(f"{prog}: error: --markdown {path}: no such file", file=sys.stderr)
        return 2
    print(render(json.loads(path.read_text()), path.name))
    return 0


def emit(out: dict[str, object], path: Path | None) -> None:
    """Print `out` as JSON and, with `path`, write it there atomically."""
    text = json.dumps(out, indent=1)
    print(text)
    if path is not None:
        from gazereg.runtime.io import atomic_write_text

        atomic_write_text(path, text + "\n")
