"""benchmarks/bench_real_size.py with --tiny: every configuration builds, trains interleaved gaze / no-gaze steps
(with and without gradient checkpointing for pi0 / pi05), and the image tokens each camera gives the model equal
its gaze distribution's length and the processor's grid; bad options are refused in one line."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "bench_real_size.py"


def _bench_module():
    # as `python benchmarks/bench_real_size.py` would: its own folder on the path, for the shared _timing module
    if str(SCRIPT.parent) not in sys.path:
        sys.path.insert(0, str(SCRIPT.parent))
    spec = importlib.util.spec_from_file_location("bench_real_size", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _run(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1"}
    return subprocess.run(
        [sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=600, env=env, cwd=ROOT
    )


@pytest.fixture(scope="module")
def tiny_result(tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("bench") / "tiny.json"
    r = _run("--tiny", "--rounds", "2", "--warmup", "0", "--batch", "2", "--out", str(out))
    assert r.returncode == 0, r.stderr[-3000:]
    assert "time x" in r.stdout  # the summary table
    return json.loads(out.read_text())


def test_every_config_runs_gaze_and_plain_steps(tiny_result):
    m = tiny_result["machine"]
    assert m["device"] == "cpu" and m["dtype"] in ("float32", "bfloat16") and m["torch_cpu_capability"]
    assert m["versions"]["lerobot"] == "0.6.1" and m["versions"]["torch"] and m["versions"]["transformers"]
    assert set(tiny_result["configs"]) == {"smolvla", "pi0", "pi05"}
    for name, e in tiny_result["configs"].items():
        assert "error" not in e and "skipped" not in e, (name, e)
        model = e["model"]
        assert model["params_total"] >= model["params_trainable"] >= model["params_with_grad"] > 0
        # smolvla has no gradient checkpointing in lerobot 0.6.1; pi0 / pi05 are measured with and without
        want = [False] if name == "smolvla" else [False, True]
        assert [r["gradient_checkpointing"] for r in e["runs"]] == want
        for run in e["runs"]:
            assert run["rounds"] == 2 and len(run["gaze"]["step_s"]) == len(run["plain"]["step_s"]) == 2
            # the gaze mode ran the gaze term, the plain mode the parent policy's forward only
            assert (
                math.isfinite(run["gaze"]["info"]["loss/gaze_kl"]) and run["gaze"]["info"]["loss/gaze_kl"] > 0
            )
            assert run["gaze"]["info"]["gaze/weight"] == 0.1
            assert "loss/gaze_kl" not in run["plain"]["info"]
            for key in ("time", "peak_memory", "step_memory"):
                assert math.isfinite(run["ratio"][key]) and run["ratio"][key] > 0
            assert run["gaze"]["peak_bytes"] > 0 and run["plain"]["peak_bytes"] > 0


def test_grid_check_per_camera(tiny_result):
    for name, e in tiny_result["configs"].items():
        grid = e["grid_check"]
        cams = e["model"]["cameras"]
        assert set(grid["cameras"]) == set(cams) and len(cams) == (2 if name == "smolvla" else 3)
        for cam, row in grid["cameras"].items():
            assert row["tokens_seen"] == row["gaze_len"] == grid["processor_grid"] > 0, (name, cam, row)
        # the regularized camera stores a frame of another aspect than the model's input: mapped through padding
        first = next(iter(cams))
        assert cams[first] != e["model"]["input_hw"] and grid["cameras"][first]["ok"]
        assert grid["attention_len"] == grid["processor_grid"] and grid["ok"]


def test_grid_check_fails_on_a_token_count_mismatch(tmp_path):
    """The check is not vacuous: a camera whose embedded token count differs from its gaze grid fails it."""
    import argparse

    import torch

    bench = _bench_module()
    args = argparse.Namespace(tiny=True, params_only=False, seed=0, cameras=None, gaze_weight=0.1)
    policy, _ = bench.build("smolvla", args, tmp_path, "cpu", False)
    batch = bench.make_batch(policy, 2, "cpu", 0)
    loss, _ = policy.forward(dict(batch))
    assert torch.isfinite(loss)
    assert bench.grid_check("smolvla", policy, batch)["ok"]
    policy.gaze_capture.state.image_tokens[1] += 1
    check = bench.grid_check("smolvla", policy, batch)
    assert not check["ok"] and not check["cameras"]["observation.images.wrist"]["ok"]
    assert check["cameras"]["observation.images.front"]["ok"]


def test_a_config_that_does_not_fit_is_skipped_before_it_is_built(tmp_path, monkeypatch):
    """The memory check runs on the meta-device build: with no free memory the real model is never built."""
    bench = _bench_module()
    built = []
    real_build = bench.build
    monkeypatch.setattr(
        bench, "build", lambda *a, **k: built.append(k.get("meta", False)) or real_build(*a, **k)
    )
    monkeypatch.setattr(bench, "available_bytes", lambda device: 1)
    args = bench.parse_args(["--tiny", "--configs", "pi0"])
    entry = bench.measure("pi0", args, tmp_path, False)
    assert built == [True] and "runs" not in entry
    assert (
        entry["skipped"].startswith("weights + gradients + AdamW need")
        and "--no-fit-check" in entry["skipped"]
    )
    assert entry["model"]["weights_grads_adam_bytes"] > 0


def test_params_only_counts_without_running(tmp_path):
    out = tmp_path / "p.json"
    r = _run("--tiny", "--params-only", "--configs", "pi05,smolvla", "--out", str(out))
    assert r.returncode == 0, r.stderr[-3000:]
    res = json.loads(out.read_text())
    assert list(res["configs"]) == ["pi05", "smolvla"]
    for e in res["configs"].values():
        assert e["model"]["params_total"] > 0 and "runs" not in e and "grid_check" not in e


@pytest.mark.parametrize(
    ("args", "option"),
    [
        (["--configs", "smolvla,pi1"], "--configs"),
        (["--configs", "pi0,pi0"], "--configs"),
        (["--rounds", "0"], "--rounds"),
        (["--gaze-weight", "0"], "--gaze-weight"),
        (["--pi-depth", "19"], "--pi-depth"),
        (["--device", "tpu"], "--device"),
    ],
)
def test_bad_options_one_line_exit_2(args, option, tmp_path):
    out = tmp_path / "x.json"
    r = _run(*args, "--out", str(out))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bench_real_size: error:") and option in lines[0], r.stderr
    assert not out.exists()
