"""`gazereg experiment`: demos -> priors -> training -> evaluation -> report, stage by stage and resumable.

`config` holds the configuration and its presets (`config_sims` the other simulators', `config_finetune`
the pretraining study's), `arms` what each arm trains on, `demos` and `glc` the
demos stage's collections and the glc arm's GLC, `records` the saved config and the report's spec, `runner` the
stages (see `gazereg.experiment.runner`), `finished` the one reader of a finished run folder or its archive
(`read_run`; `read_report` also reads a pooled report's report.json), `finished_pretrain` that of a finished
`gazereg pretrain` folder or its archive (`read_pretraining`), `pool` one report over folders that each ran
some training seeds, `archive` a finished run's records to commit, `compare` two runs side by side, `reuse` a
new folder from another's demos and priors, `cli` the command.
Runs are named by `gazereg.report.ids.RunId` (arm, training seed, step).
"""

from gazereg.experiment.arms import PriorSpec, arm_prior
from gazereg.experiment.cli import main
from gazereg.experiment.config import PRESETS, ExperimentConfig, full, paper, quick, smoke
from gazereg.experiment.config_finetune import ml45_finetune, ml45_scratch
from gazereg.experiment.config_sims import libero, libero_smoke
from gazereg.experiment.finished import FinishedRun, read_report, read_run
from gazereg.experiment.finished_pretrain import FinishedPretraining, is_pretraining, read_pretraining
from gazereg.experiment.runner import STAGES, Experiment

__all__ = [
    "PRESETS",
    "STAGES",
    "Experiment",
    "ExperimentConfig",
    "FinishedPretraining",
    "FinishedRun",
    "PriorSpec",
    "arm_prior",
    "full",
    "is_pretraining",
    "libero",
    "libero_smoke",
    "main",
    "ml45_finetune",
    "ml45_scratch",
    "paper",
    "quick",
    "read_pretraining",
    "read_report",
    "read_run",
    "smoke",
]
