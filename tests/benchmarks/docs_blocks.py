"""What the tests of the benchmarks' docs blocks share (imported as `docs_blocks`: pytest puts this folder on the
path): a benchmark script's `--markdown` mode. A block's text on a docs page is read by the script that writes
the blocks (`script.read_block`, the `script` fixture of tests/conftest.py)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def markdown(script: str, json_path: Path) -> subprocess.CompletedProcess:
    """`python benchmarks/<script> --markdown <json_path>`, its output captured."""
    cmd = [sys.executable, str(ROOT / "benchmarks" / script), "--markdown", str(json_path)]
    return subprocess.run(cmd, capture_output=True, text=True)
