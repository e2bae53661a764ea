"""scripts/study_finetune.py: the fine-tuning study's sittings in order, each one `gazereg experiment` of a study
preset at one training seed (its demonstrations copied from the preset's first sitting when that is here), the
pool of the archived seeds, and the GLC it needs refused in one line when missing. Nothing trains."""

from __future__ import annotations

import pytest

from gazereg.experiment.tuning import built_config


@pytest.fixture
def study(tmp_path, monkeypatch, load_script):
    module = load_script("scripts/study_finetune.py")
    monkeypatch.setattr(module, "ROOT", tmp_path)
    return module


def test_sittings_alternate_the_demonstration_counts_seed_by_seed(study):
    assert study.NAMES == ["study10-s0", "study50-s0", "study10-s1", "study50-s1", "study10-s2", "study50-s2"]


def test_a_sittings_command_is_its_preset_at_its_seed_with_the_first_sittings_data_when_here(study, tmp_path):
    s0, s1 = study.Sitting("study50", 0), study.Sitting("study50", 1)
    assert s1.command() == [
        "gazereg", "experiment", "--preset", "ml45_study50", "--train-seeds", "1", "--out", "runs/study50-s1"
    ]  # fmt: skip
    cfg = built_config(tuple(s1.command()))
    assert cfg.train_seeds == (1,) and cfg.demos_per_task == 50
    assert s0.data_from() == [] and s1.data_from() == []
    (tmp_path / "runs" / "study50-s0" / "stages").mkdir(parents=True)
    (tmp_path / "runs" / "study50-s0" / "stages" / "demos.json").write_text("{}")
    assert s1.data_from() == ["--data-from", "runs/study50-s0"] and s0.data_from() == []
    assert study.Sitting("study10", 1).data_from() == []  # another preset's demonstrations


def test_the_pool_takes_the_archived_seeds_of_each_preset(study, tmp_path):
    assert study.pool_command("study10") is None
    for name in ("study10-s0", "study10-s2", "study50-s1"):
        (tmp_path / "docs" / "records" / name).mkdir(parents=True)
        (tmp_path / "docs" / "records" / name / "archive.json").write_text("{}")
    assert study.pool_command("study10") == [
        "gazereg", "pool", "--preset", "ml45_study", "--train-seeds", "0", "2",
        "--runs", "docs/records/study10-s0", "docs/records/study10-s2", "--out", "runs/study10",
    ]  # fmt: skip
    assert study.pool_command("study50")[5:7] == ["1", "--runs"]


def test_a_missing_glc_is_one_line_and_exit_2_before_anything_runs(study, monkeypatch, capsys):
    monkeypatch.setattr(study, "run_experiment", lambda *a: pytest.fail("ran without the GLC"))
    assert study.main(["--sitting", "study10-s0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "runs/glc-ml45/final" in err and "gazereg glc train" in err
