"""scripts/study_finetune.py: the fine-tuning study's sittings in order, each one `gazereg experiment` of two arms
of a study preset at one training seed (its demonstrations copied from the preset's first sitting when that is
here), the pool of the archived sittings, and the GLC a glc sitting builds first when it is missing. Nothing
trains."""

from __future__ import annotations

import pytest

from gazereg.experiment.tuning import built_config


@pytest.fixture
def study(tmp_path, monkeypatch, load_script):
    module = load_script("scripts/study_finetune.py")
    monkeypatch.setattr(module, "ROOT", tmp_path)
    return module


def test_sittings_take_both_arm_pairs_and_alternate_the_demonstration_counts_seed_by_seed(study):
    names = [f"study{n}-s{seed}{pair}" for seed in (0, 1, 2) for n in (10, 50) for pair in ("", "-glc")]
    assert names == study.NAMES
    preset_arms = built_config(("gazereg", "experiment", "--preset", "ml45_study")).arms
    assert sorted(a for pair in study.ARM_PAIRS for a in pair) == sorted(preset_arms)


def test_a_sittings_command_is_its_arms_at_its_seed_with_the_first_sittings_data_when_here(study, tmp_path):
    s0, s1 = study.Sitting("study50", 0), study.Sitting("study50", 1)
    s0_glc = study.Sitting("study50", 0, ("glc", "uniform"))
    assert s1.command() == [
        "gazereg", "experiment", "--preset", "ml45_study50", "--train-seeds", "1", "--arms", "baseline", "gaze",
        "--out", "runs/study50-s1",
    ]  # fmt: skip
    cfg = built_config(tuple(s1.command()))
    assert cfg.train_seeds == (1,) and cfg.demos_per_task == 50 and cfg.arms == ("baseline", "gaze")
    assert s0_glc.name == "study50-s0-glc" and s0_glc.command()[-5:] == [
        "--arms", "glc", "uniform", "--out", "runs/study50-s0-glc"
    ]  # fmt: skip
    assert s0.data_from() == [] and s1.data_from() == [] and s0_glc.data_from() == []
    (tmp_path / "runs" / "study50-s0" / "stages").mkdir(parents=True)
    (tmp_path / "runs" / "study50-s0" / "stages" / "demos.json").write_text("{}")
    assert s1.data_from() == s0_glc.data_from() == ["--data-from", "runs/study50-s0"] and s0.data_from() == []
    assert study.Sitting("study10", 1).data_from() == []  # another preset's demonstrations


def _archive(tmp_path, *names):
    for name in names:
        (tmp_path / "docs" / "records" / name).mkdir(parents=True)
        (tmp_path / "docs" / "records" / name / "archive.json").write_text("{}")


def test_the_pool_takes_the_archived_seeds_at_the_arm_pairs_each_has(study, tmp_path):
    assert study.pool_command("study10") is None
    _archive(tmp_path, "study10-s0", "study10-s0-glc", "study10-s2", "study50-s1-glc")
    assert study.pool_command("study10") == [
        "gazereg", "pool", "--preset", "ml45_study", "--train-seeds", "0", "2", "--arms", "baseline", "gaze",
        "--runs", "docs/records/study10-s0", "docs/records/study10-s2", "--out", "runs/study10",
    ]  # fmt: skip
    assert study.pool_command("study50")[5:10] == ["1", "--arms", "glc", "uniform", "--runs"]
    _archive(tmp_path, "study10-s2-glc")
    assert study.pool_command("study10")[7:16] == [
        "--arms", "baseline", "gaze", "glc", "uniform", "--runs", "docs/records/study10-s0",
        "docs/records/study10-s0-glc", "docs/records/study10-s2",
    ]  # fmt: skip


def test_a_glc_sitting_builds_the_missing_glc_first_and_the_gaze_pair_does_not(study, tmp_path, monkeypatch):
    ran = []
    monkeypatch.setattr(study, "run_experiment", lambda cmd, root: ran.append(cmd[:3]))
    monkeypatch.setattr(study, "archived_run", lambda *a: None)
    assert study.main(["--sitting", "study10-s0"]) == 0
    assert ran == [["gazereg", "experiment", "--preset"]]
    ran.clear()
    assert study.main(["--sitting", "study10-s0-glc"]) == 0
    assert ran == [
        ["gazereg", "pretrain", "--preset"], ["gazereg", "glc", "train"], ["gazereg", "experiment", "--preset"]
    ]  # fmt: skip
    assert study.GLC_TRAIN[-1] + "/final" == study.GLC_ML45.as_posix()
    ran.clear()  # the demonstrations here: only the GLC is trained; the GLC here: nothing is built
    (tmp_path / "runs" / "pretrain" / "stages").mkdir(parents=True)
    (tmp_path / "runs" / "pretrain" / "stages" / "demos.json").write_text("{}")
    study.build_glc()
    assert ran == [["gazereg", "glc", "train"]]
    (tmp_path / study.GLC_ML45).mkdir(parents=True)
    (tmp_path / study.GLC_ML45 / "config.json").write_text("{}")
    ran.clear()
    study.build_glc()
    assert ran == []
