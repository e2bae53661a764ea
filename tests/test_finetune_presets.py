"""The pretraining study's experiment presets (issue 36 item 2): fine-tuning the ML45 generalist and training the
same run from scratch differ only in where the weights start, on ML45's held-out tasks."""

from __future__ import annotations

from dataclasses import replace

from gazereg.envs.metaworld.ml45 import ml45_split
from gazereg.experiment.config import PRESETS
from gazereg.experiment.config_finetune import GENERALIST
from gazereg.experiment.pretrain_config import PRESETS as PRETRAIN_PRESETS
from gazereg.experiment.pretrain_config import finetune_flags
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
