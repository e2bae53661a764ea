"""The real-size benchmark's block in docs/speed.md is what `bench_real_size.py --markdown` renders from the
committed JSON (so its numbers come from the file, not typed), and the markdown mode needs no LeRobot."""

from __future__ import annotations

import pytest
from docs_blocks import ROOT, markdown

BLOCKS = {  # the docs/speed.md block -> the JSON it is rendered from
    "real-size-h200": "real_size_h200.json",
    "real-size-cpu-smolvla": "real_size_cpu_smolvla.json",
    "real-size-cpu-pi-reduced": "real_size_cpu_pi_reduced.json",
}


@pytest.mark.parametrize("marker", sorted(BLOCKS))
def test_the_speed_page_block_is_rendered_from_the_committed_json(script, marker):
    done = markdown("bench_real_size.py", ROOT / "docs" / "benchmarks" / BLOCKS[marker])
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert script.read_block(ROOT / "docs" / "speed.md", marker) == out
    assert "| smolvla |" in out or ("| pi0 |" in out and "| pi05 |" in out)


def test_markdown_of_a_missing_file_is_one_line_and_exit_2(tmp_path):
    r = markdown("bench_real_size.py", tmp_path / "x.json")
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "x.json" in r.stderr
