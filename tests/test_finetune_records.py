"""The pretraining study's blocks on docs/pretraining.md recompute from the committed archives (issue 36): the
generalist's block from docs/records/pretrain-ml45, and each pretrained-against-from-scratch comparison from the
two fine-tuning runs' archives, exactly as `scripts/update_results.py` renders them (the block's run paths
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


def test_the_generalists_block_is_its_archive_rendered(script):
    assert (
        script.read_block(PAGE, "pretrain-ml45") == read_pretraining(ROOT / RECORDS / "pretrain-ml45").block()
    )


@pytest.mark.parametrize("marker", sorted(COMPARISONS))
def test_each_comparison_block_is_its_two_archives_compared(script, marker, monkeypatch):
    scratch, pretrained = (RECORDS / name for name in COMPARISONS[marker])
    monkeypatch.chdir(ROOT)  # the block names the archives by their paths from the repository root
    block = compare_markdown(compare_runs(scratch, pretrained), level=4)
    assert script.read_block(PAGE, marker) == block
    assert "What differs: `train.init_from` None -> 'models/ml45'" in block  # nothing but the initialisation
    a, b = read_run(scratch), read_run(pretrained)
    assert a.config["demos_per_task"] == b.config["demos_per_task"] == int(marker[2:4])
