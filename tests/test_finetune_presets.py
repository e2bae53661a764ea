"""The pretraining study's experiment presets (issue 36 item 2): fine-tuning the ML45 generalist and training the
same run from scratch differ only in where the weights start, on ML45's held-out tasks."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from gazereg.envs.metaworld.ml45 import ml45_split
from gazereg.experiment.config import PRESETS
from gazereg.experiment.config_finetune import GENERALIST, GLC_ML45
from gazereg.experiment.finished import recorded_precision
from gazereg.experiment.pretrain_config import PRESETS as PRETRAIN_PRESETS
from gazereg.experiment.pretrain_config import finetune_flags
from gazereg.experiment.tuning import built_config
from gazereg.runtime.config import to_dict


def test_finetune_and_scratch_differ_only_in_the_initialisation_and_folder():
    ft, sc = PRESETS["ml45_finetune"](), PRESETS["ml45_scratch"]()
    assert ft.train.init_from == GENERALIST and sc.train.init_from is None
    same = replace(sc, out=ft.out, train=replace(sc.train, init_from=ft.train.init_from))
    assert to_dict(same) == to_dict(ft)


def test_finetune_runs_on_the_held_out_tasks_with_the_generalists_architecture():
    ft = PRESETS["ml45_finetune"]()
    assert ft.tasks == ml45_split().test
    generalist = PRETRAIN_PRESETS["ml45"]().train.policy
    assert finetune_flags(ft.train.policy) == finetune_flags(generalist)
    assert set(ft.train.data.extra_instructions) <= set(
        PRETRAIN_PRESETS["ml45"]().train.data.extra_instructions
    )


def test_the_study_is_the_finetuning_preset_at_the_tunings_choice(load_script):
    """`ml45_study`'s recipe and gaze term are what the tuning chose on validation setups
    (scripts/tune_finetune.py over the committed archives, docs/tuning/finetune.md): the overrides of the
    deepest finished step, applied to `ml45_finetune`; the rest is the study's design."""
    tune = load_script("scripts/tune_finetune.py", "tune_finetune_study")
    chosen = [c for _, _, c in tune.plan() if c is not None and c.step.chained]
    assert chosen, "no step of the tuning chain has finished"
    tuned = built_config(("gazereg", "experiment", "--preset", "ml45_finetune", *chosen[-1].overrides))
    study, study50 = PRESETS["ml45_study"](), PRESETS["ml45_study50"]()
    assert study.train.steps == tuned.train.steps and study.train.optim == tuned.train.optim
    assert study.train.init_from == tuned.train.init_from == GENERALIST
    for key in ("weight", "queries", "layers"):
        assert getattr(study.train.gaze, key) == getattr(tuned.train.gaze, key), key
    controls = ("same_task", "other_episode", "perturbed", "location")
    assert study.arms == ("baseline", "gaze", "glc", "uniform", *controls)
    assert study50.arms == study.arms[:4] and study.train_seeds == (0, 1, 2)
    assert study.glc.checkpoint == GLC_ML45 and study.eval.seed_start == 1000
    assert (study.demos_per_task, study50.demos_per_task) == (10, 50)
    assert to_dict(replace(study50, out=study.out, demos_per_task=10, arms=study.arms)) == to_dict(study)


def test_the_study_trains_in_float32_as_every_archived_sitting_did():
    """The study's sittings run on whichever CPU a session gets: the preset pins float32, and every archived
    sitting's runs recorded float32 (those saved with "auto" before the pin included), so no block mixes
    precisions."""
    assert PRESETS["ml45_study"]().train.mixed_precision == "no"
    sittings = sorted(Path("docs/records").glob("study*-s*"))
    assert sittings, "no archived sitting of the study"
    assert {s.name: recorded_precision(s) for s in sittings} == {s.name: "no" for s in sittings}


def test_the_demo_is_the_study_shortened_on_two_held_out_tasks_of_its_own():
    """`make demo` (`demo`): the study's recipe, gaze term and demonstrations, on DEMO_TASKS, baseline and gaze,
    fewer steps, one seed, evaluation setups of its own; nothing else differs."""
    from gazereg.experiment.config_finetune import DEMO_EVAL_START, DEMO_TASKS, STUDY_GAZE

    demo, study = PRESETS["demo"](), PRESETS["ml45_study"]()
    assert set(DEMO_TASKS) < set(ml45_split().test) and demo.tasks == DEMO_TASKS
    assert demo.arms == ("baseline", "gaze") and demo.train_seeds == (0,)
    assert demo.train.init_from == GENERALIST and demo.train.gaze == STUDY_GAZE
    assert demo.train.steps < study.train.steps and demo.glc.checkpoint is None
    assert demo.eval.seed_start == DEMO_EVAL_START and demo.convergence_points == 1
    back = replace(
        demo,
        out=study.out,
        tasks=study.tasks,
        arms=study.arms,
        train_seeds=study.train_seeds,
        train=replace(demo.train, steps=study.train.steps),
        glc=study.glc,
        eval=replace(demo.eval, seed_start=study.eval.seed_start),
        convergence_points=study.convergence_points,
    )
    assert to_dict(back) == to_dict(study)


def test_the_demo_evaluates_on_setups_no_study_or_tuning_run_used():
    """Its evaluation and alignment setups are disjoint from the study's (evaluation, convergence, alignment,
    GLC demonstrations) and from every tuning run's (docs/records/tune-ft, validation setups), and inside the
    experiments' range."""
    from gazereg.envs.metaworld.setups import EXPERIMENTS
    from gazereg.experiment import read_run
    from gazereg.experiment.demos import GLC_OFFSET, HELDOUT_OFFSET

    def used(start: int, episodes: int, heldout: int, glc: int) -> set[int]:
        return (
            set(range(start, start + episodes))
            | set(range(start + HELDOUT_OFFSET, start + HELDOUT_OFFSET + heldout))
            | set(range(start + GLC_OFFSET, start + GLC_OFFSET + glc))
        )

    demo, study = PRESETS["demo"](), PRESETS["ml45_study"]()
    mine = used(demo.eval.seed_start, demo.eval.episodes, demo.heldout_per_task, 0)
    theirs = used(
        study.eval.seed_start, study.eval.episodes, study.heldout_per_task, study.glc_demos_per_task
    )
    tuning = [read_run(folder).config for folder in sorted(Path("docs/records/tune-ft").iterdir())]
    assert len(tuning) >= 19
    for c in tuning:
        theirs |= used(
            c["eval"]["seed_start"], c["eval"]["episodes"], c["heldout_per_task"], c["glc_demos_per_task"]
        )
    assert not mine & theirs
    assert min(mine) >= demo.demos_per_task + demo.demo_max_failures  # past the demonstrations and spares
    assert all(EXPERIMENTS.contains(range(s, s + 1)) for s in mine)


def test_the_demos_tasks_are_the_validation_choice():
    """DEMO_TASKS recomputed from the tuning's baseline-recipe run (ft-steps6k) on validation setups: the two
    held-out tasks whose success is nearest one half, ties to the earlier task in ML45's order."""
    from gazereg.experiment import read_run
    from gazereg.experiment.config_finetune import DEMO_TASKS

    run = read_run("docs/records/tune-ft/ft-steps6k")
    assert run.config["eval"]["seed_start"] == 1300 and run.arms == ("baseline",)
    order = ml45_split().test
    solved = {t: [r["success"] for r in run.episodes() if r["task"] == t] for t in order}
    assert all(len(v) == 20 for v in solved.values())
    ranked = sorted(order, key=lambda t: (abs(sum(solved[t]) / len(solved[t]) - 0.5), order.index(t)))
    assert tuple(t for t in order if t in ranked[:2]) == DEMO_TASKS


def test_the_demo_is_gazereg_experiments_default(monkeypatch):
    from gazereg.experiment import cli
    from gazereg.experiment.presets import KINDS

    class Built(Exception):
        pass

    def stop(cfg):
        raise Built(cfg)

    monkeypatch.setattr(cli, "preflight", stop)  # the configuration, before any work
    with pytest.raises(Built) as built:
        cli.main([])
    assert to_dict(built.value.args[0]) == to_dict(PRESETS["demo"]())
    assert KINDS[0].default == "demo"  # `gazereg presets` stars it
