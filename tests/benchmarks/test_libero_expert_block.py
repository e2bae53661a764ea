"""The four LIBERO suites' expert tables in docs/libero.md are what `bench_libero.py --markdown`
renders from the committed JSON (their numbers come from the measurement, not typed); the markdown mode needs
no LIBERO."""

from __future__ import annotations

import pytest
from docs_blocks import ROOT, markdown


@pytest.mark.parametrize("suite", ["libero_spatial", "libero_object", "libero_goal", "libero_10"])
def test_the_expert_block_is_rendered_from_the_committed_json(script, suite):
    out = markdown("bench_libero.py", ROOT / "docs" / "benchmarks" / f"{suite}_expert.json")
    assert out.returncode == 0, out.stderr
    marker = f"{suite.replace('_', '-')}-expert"
    assert script.read_block(ROOT / "docs" / "libero.md", marker) == out.stdout
    assert out.stdout.count(f"| {suite}/") == 10


def test_markdown_of_a_missing_file_is_one_line_and_exit_2(tmp_path):
    r = markdown("bench_libero.py", tmp_path / "x.json")
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "x.json" in r.stderr
