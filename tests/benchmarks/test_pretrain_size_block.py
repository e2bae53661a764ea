"""The pretraining's sizing table in docs/pretraining.md is what `bench_pretrain_size.py --markdown` renders from
the committed JSON (its numbers come from the file, not typed), and it holds the ml45 preset's size."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from gazereg.experiment.pretrain_config import ml45_policy

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "benchmarks" / "bench_pretrain_size.py"


def _block(page: Path, marker: str) -> str:
    text = page.read_text()
    return text.split(f"<!-- {marker}:start -->\n", 1)[1].split(f"<!-- {marker}:end -->", 1)[0]


def test_the_sizing_block_is_rendered_from_the_committed_json_and_measured_the_presets_size():
    json_path = ROOT / "docs" / "benchmarks" / "pretrain_size.json"
    out = subprocess.run(
        [sys.executable, str(SCRIPT), "--markdown", str(json_path)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert _block(ROOT / "docs" / "pretraining.md", "pretrain-size") == out
    p = ml45_policy()
    assert f"| {p.dim}x{p.depth} |" in out


def test_markdown_of_a_missing_file_is_one_line_and_exit_2(tmp_path):
    r = subprocess.run(
        [sys.executable, str(SCRIPT), "--markdown", str(tmp_path / "x.json")], capture_output=True, text=True
    )
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "x.json" in r.stderr
