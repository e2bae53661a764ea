"""`gazereg sittings` (gazereg.experiment.sittings): a schedule's sittings in order, each one `gazereg experiment`
of a group of arms of a preset at one training seed (its demonstrations copied from the part's first sitting
when that is here), the pool of the archived sittings, and the prerequisite a sitting's arms need built first
when it is missing. Nothing trains: the experiment and the archive are replaced by recorders."""

from __future__ import annotations

import pytest

import gazereg.experiment.sittings as sittings
from gazereg.experiment.config import PRESETS
from gazereg.experiment.config_finetune import GLC_ML45
from gazereg.experiment.tuning import built_config
from gazereg.runtime.errors import UsageError

STUDY = sittings.SCHEDULES["ml45-study"]
STUDY10, STUDY50 = STUDY.parts


@pytest.fixture
def ran(tmp_path, monkeypatch):
    """The commands run (their first three words), in tmp_path as the working directory."""
    monkeypatch.chdir(tmp_path)
    commands: list[list[str]] = []
    monkeypatch.setattr(sittings, "run_experiment", lambda cmd, root: commands.append(list(cmd[:3])))
    monkeypatch.setattr(sittings, "archived_run", lambda *a: None)
    return commands


def _touch(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("{}")


def test_every_part_names_an_experiment_preset_and_every_arm_is_in_one_sitting_per_seed():
    for schedule in sittings.SCHEDULES.values():
        for part in schedule.parts:
            assert part.preset in PRESETS
            cfg = built_config(("gazereg", "experiment", "--preset", part.preset))
            groups = schedule.arm_groups(part)
            assert [a for g in groups for a in g] == list(cfg.arms)
            assert all(len(g) <= max(1, part.group or cfg.parallel) for g in groups)
        per_part = {part: [s for s in schedule.sittings() if s.part == part] for part in schedule.parts}
        for part, runs in per_part.items():  # every group at every seed, once
            groups = schedule.arm_groups(part)
            assert sorted((s.seed, s.arms) for s in runs) == sorted(
                (x, g) for x in schedule.seeds for g in groups
            )


def test_the_study_takes_its_arm_pairs_and_alternates_the_demonstration_counts_seed_by_seed():
    """The core pairs seed by seed, alternating 10 and 50 demos; the controls at 10 demos afterwards, again
    seed by seed (they are worth their sittings only if the core arms show a gain to explain)."""
    pairs = {10: ("", "-glc"), 50: ("", "-glc")}
    core = [f"study{n}-s{seed}{pair}" for seed in (0, 1, 2) for n in (10, 50) for pair in pairs[n]]
    controls = [f"study10-s{seed}{pair}" for seed in (0, 1, 2) for pair in ("-same_task", "-perturbed")]
    assert [s.name for s in STUDY.sittings()] == core + controls
    assert STUDY.arm_groups(STUDY10) == [
        ("baseline", "gaze"),
        ("glc", "uniform"),
        ("same_task", "other_episode"),
        ("perturbed", "location"),
    ]


def test_a_libero_suite_runs_its_table_arms_seed_by_seed_and_the_shuffled_gaze_after_them_on_both_cores():
    """Baseline and gaze, then glc and uniform (the paper table's arms) at every seed; the shuffled-gaze control
    alone afterwards, its one run training with both cores' threads (an execution key: the same run)."""
    spatial = sittings.SCHEDULES["libero-spatial"]
    core = [f"libero-spatial-s{seed}{pair}" for seed in (0, 1, 2) for pair in ("", "-glc")]
    assert [s.name for s in spatial.sittings()] == core + [
        f"libero-spatial-s{x}-perturbed" for x in (0, 1, 2)
    ]
    named = {s.name: s for s in spatial.sittings()}
    assert named["libero-spatial-s1-glc"].command()[-5:] == [
        "--arms",
        "glc",
        "uniform",
        "--out",
        "runs/libero-spatial-s1-glc",
    ]
    alone = named["libero-spatial-s0-perturbed"].command()
    assert alone[alone.index("--arms") :] == [
        "--arms", "perturbed", "--threads-per-run", "2", "--out", "runs/libero-spatial-s0-perturbed"
    ]  # fmt: skip
    cfg = built_config(tuple(alone))
    assert cfg.threads_per_run == 2 and cfg.arms == ("perturbed",)


def test_libero_10_runs_one_arm_a_sitting_on_both_threads_the_table_arms_seed_by_seed():
    """A pair of LIBERO-10's arms would not finish in one session (520-step evaluations), so its part sits one
    arm at a time, on both cores' threads, the four table arms at each seed before the shuffled gaze."""
    long = sittings.SCHEDULES["libero-10"]
    table = ("", "-gaze", "-glc", "-uniform")
    names = [s.name for s in long.sittings()]
    assert names == [f"libero-10-s{x}{a}" for x in (0, 1, 2) for a in table] + [
        f"libero-10-s{x}-perturbed" for x in (0, 1, 2)
    ]
    for s in long.sittings():
        cfg = built_config(tuple(s.command()))
        assert len(s.arms) == 1 and cfg.arms == s.arms and cfg.threads_per_run == 2


def test_aloha_sits_baseline_and_gaze_then_the_gaze_controls_then_the_flat_target_seed_by_seed():
    """Two arms a sitting on one thread each; the flat target alone on both, under the name its archive
    (docs/records/aloha-s0-uniform) was made with, so the controls added after it keep that sitting's name."""
    aloha = sittings.SCHEDULES["aloha"]
    groups = [("baseline", "gaze"), ("same_task", "perturbed"), ("uniform",)]
    assert aloha.arm_groups(aloha.parts[0]) == groups
    names = [s.name for s in aloha.sittings()]
    assert names == [f"aloha-s{x}{a}" for x in (0, 1, 2) for a in ("", "-same_task", "-uniform")]
    uniform = next(s for s in aloha.sittings() if s.name == "aloha-s0-uniform").command()
    assert uniform[uniform.index("--arms") :] == [
        "--arms", "uniform", "--threads-per-run", "2", "--out", "runs/aloha-s0-uniform"
    ]  # fmt: skip


def test_a_sittings_command_is_its_arms_at_its_seed_with_another_sittings_data_when_here(tmp_path):
    named = {s.name: s for s in STUDY.sittings()}
    s0, s0_glc, s1 = named["study50-s0"], named["study50-s0-glc"], named["study50-s1"]
    assert s1.command() == [
        "gazereg", "experiment", "--preset", "ml45_study50", "--train-seeds", "1", "--arms", "baseline", "gaze",
        "--out", "runs/study50-s1",
    ]  # fmt: skip
    cfg = built_config(tuple(s1.command()))
    assert cfg.train_seeds == (1,) and cfg.demos_per_task == 50 and cfg.arms == ("baseline", "gaze")
    assert s0_glc.name == "study50-s0-glc" and s0_glc.command()[-5:] == [
        "--arms", "glc", "uniform", "--out", "runs/study50-s0-glc"
    ]  # fmt: skip
    assert [sittings.data_from(STUDY, s, tmp_path) for s in (s0, s0_glc, s1)] == [[], [], []]
    _touch(tmp_path / "runs" / "study50-s0" / "stages" / "demos.json")
    first = ["--data-from", "runs/study50-s0"]
    assert [sittings.data_from(STUDY, s, tmp_path) for s in (s0, s0_glc, s1)] == [[], first, first]
    assert sittings.data_from(STUDY, named["study10-s1"], tmp_path) == []  # another preset's demonstrations
    # without the part's first sitting here, another of its sittings that is (not itself, not another part's)
    (tmp_path / "runs" / "study50-s0" / "stages" / "demos.json").unlink()
    _touch(tmp_path / "runs" / "study50-s1" / "stages" / "demos.json")
    later = ["--data-from", "runs/study50-s1"]
    assert [sittings.data_from(STUDY, s, tmp_path) for s in (s0, s0_glc, s1)] == [later, later, []]
    assert sittings.data_from(STUDY, named["study10-s1"], tmp_path) == []


def _archive(root, *names):
    for name in names:
        _touch(root / "docs" / "records" / name / "archive.json")


def test_the_pool_takes_the_largest_complete_block_of_archived_seeds_and_arm_groups(tmp_path):
    assert sittings.pool_command(STUDY, STUDY10, tmp_path) is None
    _archive(tmp_path, "study10-s0", "study10-s0-glc", "study10-s2", "study50-s1-glc")
    assert sittings.pool_command(STUDY, STUDY10, tmp_path) == [
        "gazereg", "pool", "--preset", "ml45_study", "--train-seeds", "0", "2", "--arms", "baseline", "gaze",
        "--runs", "docs/records/study10-s0", "docs/records/study10-s2", "--out", "runs/study10",
        "--demos-across-machines",
    ]  # fmt: skip  # sittings run on whichever machine a session has (test_experiment_pool.py)
    assert sittings.pool_command(STUDY, STUDY50, tmp_path)[5:10] == [
        "1",
        "--arms",
        "glc",
        "uniform",
        "--runs",
    ]
    _archive(tmp_path, "study10-s2-glc")
    assert sittings.pool_command(STUDY, STUDY10, tmp_path)[7:16] == [
        "--arms", "baseline", "gaze", "glc", "uniform", "--runs", "docs/records/study10-s0",
        "docs/records/study10-s0-glc", "docs/records/study10-s2",
    ]  # fmt: skip
    # study50-s1-glc archived above; seed 2 opened:
    _archive(tmp_path, "study50-s0", "study50-s0-glc", "study50-s1", "study50-s2")
    assert sittings.pool_command(STUDY, STUDY50, tmp_path)[5:13] == [
        "0", "1", "--arms", "baseline", "gaze", "glc", "uniform", "--runs",
    ]  # fmt: skip  # 4 arms x 2 seeds, not 2 arms x 3 seeds: a new seed does not shrink the pool's arms
    _archive(tmp_path, "study50-s2-glc")
    assert sittings.pool_command(STUDY, STUDY50, tmp_path)[5:14] == [
        "0", "1", "2", "--arms", "baseline", "gaze", "glc", "uniform", "--runs",
    ]  # fmt: skip


def test_the_next_sitting_is_the_first_not_archived_and_a_glc_sitting_builds_the_missing_glc_first(
    tmp_path, ran, monkeypatch
):
    pooled: list[list[str]] = []
    monkeypatch.setattr(sittings, "pool_main", pooled.append)
    assert sittings.main(["ml45-study"]) == 0
    assert ran == [["gazereg", "experiment", "--preset"]] and pooled == []  # study10-s0: no GLC needed
    _archive(tmp_path, "study10-s0")
    ran.clear()
    assert sittings.main(["ml45-study"]) == 0  # study10-s0-glc
    assert ran == [
        ["gazereg", "pretrain", "--preset"], ["gazereg", "glc", "train"], ["gazereg", "experiment", "--preset"]
    ]  # fmt: skip
    assert pooled == [sittings.pool_command(STUDY, STUDY10, tmp_path)[2:]]
    assert sittings.STUDY_GLC.steps[-1].command[-1] + "/final" == GLC_ML45.as_posix()
    ran.clear()  # the demonstrations here: only the GLC is trained; the GLC here: nothing is built
    _touch(tmp_path / "runs" / "pretrain" / "stages" / "demos.json")
    sittings.STUDY_GLC.build(tmp_path)
    assert ran == [["gazereg", "glc", "train"]]
    _touch(tmp_path / GLC_ML45 / "config.json")
    ran.clear()
    sittings.STUDY_GLC.build(tmp_path)
    assert ran == []


def test_an_unknown_sitting_is_refused_before_anything_runs(ran):
    refused = r"^--sitting 'study10-s9' is not one of ml45-study's sittings \(study10-s0, "
    with pytest.raises(UsageError, match=refused):
        sittings.main(["ml45-study", "--sitting", "study10-s9"])
    assert ran == []
