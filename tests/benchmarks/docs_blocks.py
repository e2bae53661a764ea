"""What the tests of the benchmarks' docs blocks share (imported as `docs_blocks`: pytest puts this folder on the
path): a block's text on a docs page, and a benchmark script's `--markdown` mode."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def block(page: Path, marker: str) -> str:
    """The text between `marker`'s start and end lines on `page`."""
    text = page.read_text()
    return text.split(f"<!-- {marker}:start -->\n", 1)[1].split(f"<!-- {marker}:end -->", 1)[0]


def markdown(script: str, json_path: Path) -> subprocess.CompletedProcess:
    """`python benchmarks/<script> --markdown <json_path>`, its output captured."""
    cmd = [sys.executable, str(ROOT / "benchmarks" / script), "--markdown", str(json_path)]
    return subprocess.run(cmd, capture_output=True, text=True)
