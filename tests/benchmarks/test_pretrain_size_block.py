"""The pretraining's sizing table in docs/pretraining.md is what `bench_pretrain_size.py --markdown` renders from
the committed JSON (its numbers come from the file, not typed), and it holds the ml45 preset's size."""

from __future__ import annotations

from docs_blocks import ROOT, markdown

from gazereg.experiment.pretrain_config import ml45_policy


def test_the_sizing_block_is_rendered_from_the_committed_json_and_measured_the_presets_size(script):
    out = markdown("bench_pretrain_size.py", ROOT / "docs" / "benchmarks" / "pretrain_size.json")
    assert out.returncode == 0, out.stderr
    assert script.read_block(ROOT / "docs" / "pretraining.md", "pretrain-size") == out.stdout
    p = ml45_policy()
    assert f"| {p.dim}x{p.depth} |" in out.stdout


def test_markdown_of_a_missing_file_is_one_line_and_exit_2(tmp_path):
    r = markdown("bench_pretrain_size.py", tmp_path / "x.json")
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "x.json" in r.stderr
