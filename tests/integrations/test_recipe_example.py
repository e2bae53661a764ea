import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("transformers", reason="the hf extra (transformers) is not installed")

from tiny_models import tiny_model  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
RECIPE = ROOT / "examples" / "transformers_gaze_recipe.py"
OFFLINE = {**os.environ, "HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}


def _kl(stdout: str) -> tuple[float, float]:
    first, last = re.search(r"KL\(gaze\|\|attention\) ([0-9.]+) -> ([0-9.]+)", stdout).groups()
    return float(first), float(last)


def test_transformers_recipe_runs_offline_and_the_gaze_kl_falls():
    r = subprocess.run(
        [sys.executable, str(RECIPE), "--steps", "30"],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
        env=OFFLINE,
    )
    first, last = _kl(r.stdout)
    assert last < 0.5 * first, r.stdout


def test_transformers_recipe_regularizes_local_weights(tmp_path):
    tiny_model("smolvlm").save_pretrained(tmp_path / "checkpoint")
    r = subprocess.run(
        [sys.executable, str(RECIPE), "--model", str(tmp_path / "checkpoint"), "--steps", "5"],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
        env=OFFLINE,
    )
    first, last = _kl(r.stdout)
    assert "SmolVLMForConditionalGeneration" in r.stdout and last < first, r.stdout
