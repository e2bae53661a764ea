import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("transformers", reason="the hf extra (transformers) is not installed")
ROOT = Path(__file__).resolve().parents[2]


def test_transformers_recipe_runs_offline_and_the_gaze_kl_falls():
    r = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "transformers_gaze_recipe.py"), "--steps", "30"],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
        env={**os.environ, "HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"},
    )
    first, last = map(float, re.search(r"KL\(gaze\|\|attention\) ([0-9.]+) -> ([0-9.]+)", r.stdout).groups())
    assert last < 0.5 * first, r.stdout
