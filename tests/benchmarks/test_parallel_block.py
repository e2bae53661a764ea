"""The layouts table in docs/speed.md is what `bench_parallel.py --markdown` renders from the committed JSON (its
numbers come from the file, not typed); a bad layout is refused in one line before anything runs."""

from __future__ import annotations

import subprocess
import sys

from docs_blocks import ROOT, markdown


def test_the_layouts_block_is_rendered_from_the_committed_json(script):
    out = markdown("bench_parallel.py", ROOT / "docs" / "benchmarks" / "parallel.json")
    assert out.returncode == 0, out.stderr
    assert script.read_block(ROOT / "docs" / "speed.md", "bench-parallel") == out.stdout
    assert "| 1x2 |" in out.stdout and "| 2x1 |" in out.stdout


def test_a_bad_layout_is_one_line_and_exit_2():
    cmd = [sys.executable, str(ROOT / "benchmarks" / "bench_parallel.py"), "--layouts", "2x0"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "2x0" in r.stderr
