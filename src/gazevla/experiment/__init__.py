"""`gazevla experiment`: demos -> priors -> training -> evaluation -> report, stage by stage and resumable.

`config` holds the configuration and its presets, `runner` the stages; see `gazevla.experiment.runner`.
"""

from gazevla.experiment.config import PRESETS, ExperimentConfig, arm_prior, full, paper, quick, smoke
from gazevla.experiment.runner import STAGES, Experiment, main

__all__ = [
    "PRESETS",
    "STAGES",
    "Experiment",
    "ExperimentConfig",
    "arm_prior",
    "full",
    "main",
    "paper",
    "quick",
    "smoke",
]
