"""The pretraining study's blocks on docs/pretraining.md recompute from the committed archives (issue 36): each
generalist's block from its archive in docs/records, each pretrained-against-from-
scratch comparison from the two fine-tuning runs' archives, and the longer-pretrained generalist's validation
comparisons from the tuning archives (docs/records/tune-ft), exactly as `scripts/update_results.py` renders them (the block's run paths
included)."""

from __future__ import annotations

from pathlib import Path

import pytest

from gazereg.experiment.compare import compare_runs
from gazereg.experiment.finished import read_run
from gazereg.experiment.finished_pretrain import read_pretraining
from gazereg.report.compare import compare_markdown

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "pretraining.md"
RECORDS = Path("docs") / "records"
COMPARISONS = {
    "ft10-compare": ("ft10-scratch", "ft10-pretrained"),
    "ft50-compare": ("ft50-scratch", "ft50-pretrained"),
}


@pytest.mark.parametrize("marker", ["pretrain-ml45", "pretrain-ml45-continued"])
def test_each_generalists_block_is_its_archive_rendered(script, marker):
    assert script.read_block(PAGE, marker) == read_pretraining(ROOT / RECORDS / marker).block()


VALIDATION = {
    "generalist-vs-scratch": ("tune-ft/sc-default", "tune-ft/g-continued"),
    "generalist-vs-committed": ("tune-ft/ft-steps6k", "tune-ft/g-continued"),
}
"""the longer-pretrained generalist's validation fine-tuning against scratch's and the committed one's"""


@pytest.mark.parametrize("marker", sorted(VALIDATION))
def test_each_validation_comparison_block_is_its_two_archives_compared(script, marker, monkeypatch):
    a, b = (RECORDS / name for name in VALIDATION[marker])
    monkeypatch.chdir(ROOT)
    block = compare_markdown(compare_runs(a, b), level=4)
    assert script.read_block(PAGE, marker) == block
    assert "'runs/pretrain-continued/policy'" in block  # B starts from the longer-pretrained generalist
    assert read_run(a).config["eval"]["seed_start"] == read_run(b).config["eval"]["seed_start"] == 1300


@pytest.mark.parametrize("marker", sorted(COMPARISONS))
def test_each_comparison_block_is_its_two_archives_compared(script, marker, monkeypatch):
    scratch, pretrained = (RECORDS / name for name in COMPARISONS[marker])
    monkeypatch.chdir(ROOT)  # the block names the archives by their paths from the repository root
    block = compare_markdown(compare_runs(scratch, pretrained), level=4)
    assert script.read_block(PAGE, marker) == block
    assert "What differs: `train.init_from` None -> 'models/ml45'" in block  # nothing but the initialisation
    a, b = read_run(scratch), read_run(pretrained)
    assert a.config["demos_per_task"] == b.config["demos_per_task"] == int(marker[2:4])
