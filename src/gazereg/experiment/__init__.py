"""`gazereg experiment`: demos -> priors -> training -> evaluation -> report, stage by stage and resumable.

`config` holds the configuration and its presets, `runner` the stages; see `gazereg.experiment.runner`.
Runs are named by `gazereg.report.ids.RunId` (arm, training seed, step).
"""

from gazereg.experiment.config import (
    PRESETS,
    ExperimentConfig,
    PriorSpec,
    arm_prior,
    full,
    paper,
    quick,
    smoke,
)
from gazereg.experiment.runner import STAGES, Experiment, main

__all__ = [
    "PRESETS",
    "STAGES",
    "Experiment",
    "ExperimentConfig",
    "PriorSpec",
    "arm_prior",
    "full",
    "main",
    "paper",
    "quick",
    "smoke",
]
