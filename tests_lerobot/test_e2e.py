"""The end-to-end proof through LeRobot at toy size (scripts/lerobot_e2e.py): Meta-World demos written with
lerobot's own writer, gaze priors into a new data set version, the real lerobot-train for smolvla and
smolvla_gaze, and both checkpoints evaluated on the same unseen setups through the eval adapter.

The script runs with the project venv's interpreter (Meta-World, MuJoCo, gazereg) and calls this lane's
interpreter (sys.executable) for every LeRobot step; the test skips when that venv or Meta-World is missing."""

from __future__ import annotations

import io
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "lerobot_e2e.py"
PROJECT_PYTHON = Path(os.environ.get("GAZEREG_PROJECT_PYTHON", ROOT / ".venv" / "bin" / "python"))


def test_adapter_protocol_round_trip():
    from lerobot_policy_gazereg.eval_adapter import read_message, write_message

    buf = io.BytesIO()
    write_message(buf, {"op": "act", "state": np.arange(4, dtype=np.float32), "task": "reach"})
    write_message(buf, {"op": "close"})
    buf.seek(0)
    first = read_message(buf)
    assert first["task"] == "reach" and first["state"].tolist() == [0, 1, 2, 3]
    assert read_message(buf) == {"op": "close"} and read_message(buf) is None


@pytest.fixture(scope="module")
def project_python() -> Path:
    if not PROJECT_PYTHON.exists():
        pytest.skip(f"the project venv is missing at {PROJECT_PYTHON} (GAZEREG_PROJECT_PYTHON)")
    r = subprocess.run([str(PROJECT_PYTHON), "-c", "import metaworld, mujoco, gazereg"], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"the project venv {PROJECT_PYTHON} lacks metaworld/mujoco/gazereg")
    return PROJECT_PYTHON


@pytest.mark.slow
def test_lerobot_e2e_toy(tmp_path, project_python):
    out = tmp_path / "e2e"
    cmd = [str(project_python), str(SCRIPT), f"--out={out}", f"--lane-python={sys.executable}"]
    cmd += ["--tasks", "reach-v3", "--demos=2", "--steps=2", "--eval-episodes=2", "--eval-max-steps=20"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path, env=env)
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    # the data sets: lerobot's writer, then the new version with the gaze feature
    info = json.loads((out / "lerobot_gaze" / "meta" / "info.json").read_text())
    assert {"gaze.corner2.heatmap", "gaze.corner2.valid", "observation.images.corner2"} <= set(
        info["features"]
    )
    assert info["total_episodes"] == 2
    # both arms trained with the real lerobot-train; only the gaze arm has a gaze term
    gaze_log = (out / "logs" / "4_train_smolvla_gaze.log").read_text()
    assert re.search(r"loss/gaze_kl:[0-9.]+", gaze_log), gaze_log[-2000:]
    assert "gaze_kl" not in (out / "logs" / "4_train_smolvla.log").read_text()
    # the same unseen setups for both, with intervals and the paired test
    res = json.loads((out / "results.json").read_text())
    assert res["setup_seeds"] == [1000, 1001]
    for arm in ("smolvla", "smolvla_gaze"):
        v = res["arms"][arm]
        assert len(v["success"]) == 2 and all(0 < s <= 20 for s in v["steps"])
        assert 0.0 <= v["wilson95"][0] <= v["rate"] <= v["wilson95"][1] <= 1.0
    assert 0.0 <= res["paired"]["mcnemar"]["p_value"] <= 1.0
    # attention figures: both arms' attention next to the prior, with KL(gaze || attention)
    assert (out / "attention.png").stat().st_size > 0
    kl = res["attention_kl_gaze_to_attention"]
    assert set(kl) == {"smolvla", "smolvla_gaze"} and all(v is not None and v >= 0 for v in kl.values())
    assert "McNemar p =" in r.stdout and "wall time" in r.stdout


@pytest.mark.slow
def test_lerobot_e2e_toy_with_glc_priors(tmp_path, project_python):
    """--gaze-source glc: GLC trained on demos of its own setups predicts the priors from the frames alone; its
    held-out quality is in the results, and the gaze feature comes from its prior."""
    out = tmp_path / "e2e"
    cmd = [str(project_python), str(SCRIPT), f"--out={out}", f"--lane-python={sys.executable}"]
    cmd += ["--tasks", "reach-v3", "--demos=2", "--steps=2", "--eval-episodes=1", "--eval-max-steps=10"]
    cmd += ["--gaze-source=glc", "--glc-demos=5", "--glc-steps=2"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path, env=env)
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    res = json.loads((out / "results.json").read_text())
    assert res["gaze_source"] == "glc"
    g = res["glc"]
    assert g["heldout_episodes"] >= 1 and all(
        0.0 <= g[k] <= 1.0 for k in ("glc_f1", "glc_auc", "centre_prior_f1")
    )
    # GLC's seeds come after the policy's demos and before the evaluation's
    attempts = (out / "glc_collected" / "collect" / "attempts.jsonl").read_text().splitlines()
    seeds = {json.loads(line)["record"]["seed"] for line in attempts}
    assert seeds and min(seeds) >= 2 + 20 and max(seeds) < 1000, seeds  # after demos + MAX_FAILURES
    manifest = json.loads((out / "imported" / "priors" / "glc" / "prior.json").read_text())
    assert manifest["source"]["name"] == "glc"
    assert "GLC on 1 held-out episodes" in r.stdout


def test_seed_ranges_that_reach_the_evaluation_are_refused(tmp_path, project_python):
    cmd = [str(project_python), str(SCRIPT), f"--out={tmp_path / 'e2e'}", "--demos=2", "--gaze-source=glc"]
    r = subprocess.run([*cmd, "--glc-demos=990"], capture_output=True, text=True, timeout=120)
    assert r.returncode != 0 and "overlap the GLC demos'" in r.stderr, r.stderr[-2000:]
    assert not (tmp_path / "e2e").exists()
