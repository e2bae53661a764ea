"""The real-size benchmark's block in docs/speed.md is what `bench_real_size.py --markdown` renders from the
committed JSON (so its numbers come from the file, not typed), and the markdown mode needs no LeRobot."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BLOCKS = {  # the docs/speed.md block -> the JSON it is rendered from
    "real-size-h200": "real_size_h200.json",
    "real-size-cpu-smolvla": "real_size_cpu_smolvla.json",
    "real-size-cpu-pi-reduced": "real_size_cpu_pi_reduced.json",
}


def _block(page: Path, marker: str) -> str:
    text = page.read_text()
    return text.split(f"<!-- {marker}:start -->\n", 1)[1].split(f"<!-- {marker}:end -->", 1)[0]


@pytest.mark.parametrize("marker", sorted(BLOCKS))
def test_the_speed_page_block_is_rendered_from_the_committed_json(marker):
    json_path = ROOT / "docs" / "benchmarks" / BLOCKS[marker]
    out = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_real_size.py"), "--markdown", str(json_path)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert _block(ROOT / "docs" / "speed.md", marker) == out
    assert "| smolvla |" in out or ("| pi0 |" in out and "| pi05 |" in out)


def test_markdown_of_a_missing_file_is_one_line_and_exit_2(tmp_path):
    r = subprocess.run(
        [
            sys.executable,
            str(ROOT / "benchmarks" / "bench_real_size.py"),
            "--markdown",
            str(tmp_path / "x.json"),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "x.json" in r.stderr
