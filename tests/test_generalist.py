"""The committed ML45 generalist (models/ml45, issue 36 item 1): the weights its manifest names, the architecture
the fine-tuning presets build, a tokenizer that knows every held-out instruction, and the same manifest as the
archived pretraining record it was copied with (docs/records/pretrain-ml45)."""

from __future__ import annotations

import json
from pathlib import Path

from gazereg.experiment.config import PRESETS
from gazereg.experiment.config_finetune import GENERALIST
from gazereg.experiment.finished_pretrain import read_pretraining
from gazereg.experiment.pretrain_config import finetune_flags, held_out_instructions, ml45_policy
from gazereg.policies.base import MODEL_FILE
from gazereg.training.init_from import file_sha256, read_init

ROOT = Path(__file__).resolve().parents[1]
FOLDER = ROOT / GENERALIST
RECORD = ROOT / "docs" / "records" / "pretrain-ml45"


def test_the_weights_are_the_ones_the_manifest_and_the_archived_record_name():
    manifest = json.loads((FOLDER / "manifest.json").read_text())
    sha = file_sha256(FOLDER / MODEL_FILE)
    assert manifest["policy"]["model_sha256"] == sha
    assert read_pretraining(RECORD).manifest["policy"]["model_sha256"] == sha
    assert (FOLDER / MODEL_FILE).stat().st_size < 25 * 2**20


def test_the_generalist_has_the_fine_tuning_presets_architecture_and_knows_the_held_out_words():
    policy = read_init(FOLDER, "vla")
    arch = ml45_policy()
    for name in ("dim", "depth", "heads", "chunk", "max_text_len", "tokenizer", "image_hw", "patch_size"):
        assert getattr(policy.config, name) == getattr(arch, name), name
    manifest = json.loads((FOLDER / "manifest.json").read_text())
    assert manifest["policy"]["finetune_flags"] == finetune_flags(PRESETS["ml45_finetune"]().train.policy)
    for text in held_out_instructions():
        assert policy.tokenizer.unknown_words(text) == [], text
