"""The LIBERO-Spatial placement tables in docs/libero.md are what `libero_placements.py --markdown` renders from
the committed JSONs (the check on the env before the fixture fix, and after it); the markdown mode needs no
LIBERO. The JSONs say what the fix did: sampled placements with an object falling before, none after."""

from __future__ import annotations

import json

import pytest
from docs_blocks import ROOT, markdown

BENCH = ROOT / "docs" / "benchmarks"


@pytest.mark.parametrize("name", ["libero_spatial_placements_f741880", "libero_spatial_placements"])
def test_the_placement_block_is_rendered_from_the_committed_json(script, name):
    out = markdown("libero_placements.py", BENCH / f"{name}.json")
    assert out.returncode == 0, out.stderr
    assert script.read_block(ROOT / "docs" / "libero.md", name.replace("_", "-")) == out.stdout
    assert out.stdout.count("| libero_spatial/") == 10


def test_the_fix_leaves_the_fixed_states_alone_and_settles_the_sampled_placements():
    before, after = (
        json.loads((BENCH / f"{n}.json").read_text())
        for n in ("libero_spatial_placements_f741880", "libero_spatial_placements")
    )
    assert before["source"]["commit"].startswith("f741880")
    for kind in ("fixed", "sampled"):
        assert [t[kind]["n"] for t in before["tasks"]] == [t[kind]["n"] for t in after["tasks"]]
    assert sum(t["fixed"]["unsettled"] for t in before["tasks"] + after["tasks"]) == 0
    fell = [t["task"] for t in before["tasks"] if t["sampled"]["unsettled"] == t["sampled"]["n"]]
    assert fell and all(
        next(a for a in after["tasks"] if a["task"] == t)["sampled"]["unsettled"] == 0 for t in fell
    )


def test_markdown_of_a_missing_file_is_one_line_and_exit_2(tmp_path):
    r = markdown("libero_placements.py", tmp_path / "x.json")
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "x.json" in r.stderr
