"""The evaluation and compilation benchmarks run end to end at their smallest size and print the JSON fields
the docs cite (their timings are not asserted)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"


def run_bench(script: str, *args: str) -> dict:
    done = subprocess.run(
        [sys.executable, str(BENCH / script), *args], capture_output=True, text=True, cwd=BENCH, timeout=600
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout[done.stdout.index("{") :])


@pytest.mark.sim
def test_bench_eval_reports_lockstep_and_batched_inference(gl_backend):
    out = run_bench("bench_eval.py", "--steps", "3", "--rounds", "1", "--calls", "4", "--episodes", "1",
                    "--batches", "1", "2")  # fmt: skip
    assert out["rollout_worker_run"]["batch"] == 1 and out["rollout_worker_run_batched"]["batch"] >= 2
    assert out["rollout_worker_batched_over_single"] > 0
    assert set(out["batched_select_action_ms_per_env"]) == {"float32", "bf16_autocast"}
    assert set(out["batched_ms_per_env_over_fp32_batch_first"]["float32"]) == {"1", "2"}


@pytest.mark.slow
def test_bench_compile_reports_both_compiled_paths():
    out = run_bench("bench_compile.py", "--quick", "--steps", "1", "--warmup", "1")
    assert set(out["speedup_vs_eager"]) == {"compiled", "compiled_blocks"}
    assert set(out["step_ms_median"]) == {f"{p}/{t}" for p in ("eager", "compiled", "compiled_blocks")
                                          for t in ("baseline", "gaze")}  # fmt: skip
    assert isinstance(out["graph_breaks"], dict)
