"""What each arm of an experiment trains on: its prior, the gaze source that makes it, and the GLC the glc arm
trains first. The arms are registered roles (`gazereg.training.arms`: prior, gaze target, whether a control);
this module answers for an experiment configuration.

    arm_prior("gaze", cfg)              # PriorSpec("visuomotor", VisuomotorParams())
    arm_prior("glc", cfg)               # the GLC trained in out/glc, or the checkpoint given
    arm_prior("glc", cfg, task_names)   # with cfg.glc_folds: each task's prior from the fold GLC not trained on it
    gaze_target("location")             # "features": the gaze arm's prior, predicted by a head, not attention
"""

from __future__ import annotations

from collections.abc import Mapping

from gazereg.experiment.config import ExperimentConfig
from gazereg.training.arms import (
    PriorSpec,
    arm,
    fold_tasks,
    gaze_prior,
    glc_dir,
    glc_fold_dir,
    glc_folds_source,
    trains_glc,
)

__all__ = [
    "PriorSpec",
    "arm_prior",
    "fold_tasks",
    "gaze_prior",
    "gaze_target",
    "glc_dir",
    "glc_fold_dir",
    "glc_folds_source",
    "trains_glc",
]


def arm_prior(
    name: str, cfg: ExperimentConfig, task_names: Mapping[str, str] | None = None
) -> PriorSpec | None:
    """The prior arm `name` trains on (its registered `prior`); None for the baseline. `task_names`: each
    task's name in the episode store (only the cross-fitted glc source reads it; see `glc_folds_source`).
    UnknownArm (a KeyError) names the registered arms."""
    return arm(name).prior(cfg, task_names)


def gaze_target(name: str) -> str:
    """What the arm's gaze term supervises (`GazeConfig.target`): the policy's attention, or for the
    `location` control a training-only head that predicts the same gaze distribution over the patches from
    the image tokens' features (`gazereg.training.location`). The control gets the gaze arm's prior, weight
    and layers, so it receives the same location information without any term on the attention: it separates
    attention supervision from location supervision."""
    return arm(name).target
