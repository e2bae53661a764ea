"""What each arm of an experiment trains on: its prior, the gaze source that makes it, and the GLC the glc arm
trains first.

    arm_prior("gaze", cfg)              # PriorSpec("visuomotor", VisuomotorParams())
    arm_prior("glc", cfg)               # the GLC trained in out/glc, or the checkpoint given
    arm_prior("glc", cfg, task_names)   # with cfg.glc_folds: each task's prior from the fold GLC not trained on it
    gaze_target("location")             # "features": the gaze arm's prior, predicted by a head, not attention

Cross-fitted GLC (`ExperimentConfig.glc_folds`): the tasks are split into folds; the GLC of fold k trains on
the gaze source's points of the training demonstrations of every other fold's tasks and predicts the glc prior
of fold k's tasks, so no episode's glc prior comes from a GLC that saw that task's gaze.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

from gazereg.experiment.config import ARMS, ExperimentConfig
from gazereg.gaze.sources import GazeSourceParams
from gazereg.gaze.sources.glc_folds import GLCFoldsParams, inference_settings
from gazereg.gaze.sources.perturbed import PerturbedParams
from gazereg.gaze.sources.simple import SaliencyParams, UniformParams


@dataclass(frozen=True)
class PriorSpec:
    """A prior an arm trains on: its name in the episode store and the gaze source that makes it."""

    name: str
    source: GazeSourceParams


def trains_glc(cfg: ExperimentConfig) -> bool:
    """Whether the experiment trains its own GLC (one, or one per fold): the glc arm runs and no checkpoint
    was given."""
    return "glc" in cfg.arms and cfg.glc.checkpoint is None


def glc_dir(cfg: ExperimentConfig) -> Path:
    return Path(cfg.out) / "glc"


def glc_fold_dir(cfg: ExperimentConfig, fold: int) -> Path:
    """Where the GLC that predicts the tasks of `cfg.glc_folds[fold]` trains."""
    return glc_dir(cfg) / f"fold{fold}"


def fold_tasks(cfg: ExperimentConfig, fold: int) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(the tasks the GLC of `fold` trains on, the tasks it predicts), both in `cfg.tasks`' order."""
    predicts = cfg.glc_folds[fold]
    return tuple(t for t in cfg.tasks if t not in predicts), tuple(t for t in cfg.tasks if t in predicts)


def glc_folds_source(cfg: ExperimentConfig, task_names: Mapping[str, str] | None = None) -> GLCFoldsParams:
    """The cross-fitted glc source: each task (as the store names its episodes, `task_names[task]`; the task
    itself when missing) with the final GLC of its fold, and `cfg.glc`'s inference settings."""
    names = task_names or {}
    pairs = [
        (names.get(t, t), glc_fold_dir(cfg, k) / "final")
        for k in range(len(cfg.glc_folds))
        for t in fold_tasks(cfg, k)[1]
    ]
    return GLCFoldsParams(
        tasks=tuple(t for t, _ in pairs),
        checkpoints=tuple(c for _, c in pairs),
        **inference_settings(cfg.glc),
    )


def gaze_prior(cfg: ExperimentConfig) -> PriorSpec:
    """The gaze source's own prior: the gaze arm trains on it, the perturbed controls are made from it and
    every arm's attention is measured against it."""
    return PriorSpec(cfg.gaze.name, cfg.gaze)


def arm_prior(
    arm: str, cfg: ExperimentConfig, task_names: Mapping[str, str] | None = None
) -> PriorSpec | None:
    """The prior `arm` trains on; None for the baseline. `task_names`: each task's name in the episode store
    (only the cross-fitted glc source reads it; see `glc_folds_source`)."""
    base = cfg.gaze.name
    if arm == "baseline":
        return None
    if arm in ("gaze", "location"):
        return gaze_prior(cfg)
    if arm == "perturbed":
        return PriorSpec(f"{base}-shuffled", PerturbedParams(mode="shuffle", base=base))
    if arm == "blobs":
        return PriorSpec("blobs", PerturbedParams(mode="blobs"))
    if arm == "other_episode":
        return PriorSpec(f"{base}-other-episode", PerturbedParams(mode="other_episode", base=base))
    if arm == "saliency":
        return PriorSpec("saliency", SaliencyParams())
    if arm == "uniform":
        return PriorSpec("uniform", UniformParams())
    if arm == "glc":
        if cfg.glc_folds:
            return PriorSpec("glc", glc_folds_source(cfg, task_names))
        trained = replace(cfg.glc, checkpoint=glc_dir(cfg) / "final")
        return PriorSpec("glc", trained if trains_glc(cfg) else cfg.glc)
    raise KeyError(f"unknown arm {arm!r}; choose from {sorted(ARMS)}")


def gaze_target(arm: str) -> str:
    """What the arm's gaze term supervises (`GazeConfig.target`): the policy's attention, or for the
    `location` control a training-only head that predicts the same gaze distribution over the patches from
    the image tokens' features (`gazereg.training.location`). The control gets the gaze arm's prior, weight
    and layers, so it receives the same location information without any term on the attention: it separates
    attention supervision from location supervision."""
    return "features" if arm == "location" else "attention"
