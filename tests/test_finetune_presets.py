"""The pretraining study's experiment presets (issue 36 item 2): fine-tuning the ML45 generalist and training the
same run from scratch differ only in where the weights start, on ML45's held-out tasks."""

from __future__ import annotations

from dataclasses import replace

from gazereg.envs.metaworld.ml45 import ml45_split
from gazereg.experiment.config import PRESETS
from gazereg.experiment.config_finetune import GENERALIST, GLC_ML45
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
    assert study.arms == ("baseline", "gaze", "glc", "uniform") and study.train_seeds == (0, 1, 2)
    assert study.glc.checkpoint == GLC_ML45 and study.eval.seed_start == 1000
    assert (study.demos_per_task, study50.demos_per_task) == (10, 50)
    assert to_dict(replace(study50, out=study.out, demos_per_task=10)) == to_dict(study)
