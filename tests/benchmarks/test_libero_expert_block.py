"""LIBERO-Object's expert table in docs/libero.md is what `bench_libero.py --markdown` renders from the committed
JSON (its numbers come from the measurement, not typed); the markdown mode needs no LIBERO."""

from __future__ import annotations

from docs_blocks import ROOT, markdown


def test_the_expert_block_is_rendered_from_the_committed_json(script):
    out = markdown("bench_libero.py", ROOT / "docs" / "benchmarks" / "libero_object_expert.json")
    assert out.returncode == 0, out.stderr
    assert script.read_block(ROOT / "docs" / "libero.md", "libero-object-expert") == out.stdout
    assert out.stdout.count("| libero_object/") == 10


def test_markdown_of_a_missing_file_is_one_line_and_exit_2(tmp_path):
    r = markdown("bench_libero.py", tmp_path / "x.json")
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "x.json" in r.stderr
