import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_core_api_example_runs_and_the_gaze_kl_falls():
    r = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "core_api.py")],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    kls = [float(x) for x in re.findall(r"KL\(gaze\|\|attention\) ([0-9.]+)", r.stdout)]
    assert len(kls) >= 2 and kls[-1] < 0.5 * kls[0], r.stdout
