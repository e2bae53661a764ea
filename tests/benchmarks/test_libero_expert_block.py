"""LIBERO-Object's expert table in docs/libero.md is what `bench_libero.py --markdown` renders from the committed
JSON (its numbers come from the measurement, not typed); the markdown mode needs no LIBERO."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "benchmarks" / "bench_libero.py"


def _block(page: Path, marker: str) -> str:
    text = page.read_text()
    return text.split(f"<!-- {marker}:start -->\n", 1)[1].split(f"<!-- {marker}:end -->", 1)[0]


def test_the_expert_block_is_rendered_from_the_committed_json():
    json_path = ROOT / "docs" / "benchmarks" / "libero_object_expert.json"
    out = subprocess.run(
        [sys.executable, str(SCRIPT), "--markdown", str(json_path)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert _block(ROOT / "docs" / "libero.md", "libero-object-expert") == out
    assert out.count("| libero_object/") == 10


def test_markdown_of_a_missing_file_is_one_line_and_exit_2(tmp_path):
    r = subprocess.run(
        [sys.executable, str(SCRIPT), "--markdown", str(tmp_path / "x.json")], capture_output=True, text=True
    )
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "x.json" in r.stderr
