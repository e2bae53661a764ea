"""What an experiment checks before its first stage (`preflight`): everything the stages would otherwise find
late, as one UsageError line naming the option, before anything is collected or written.

    preflight(cfg)       # tasks, --train.data.tasks, a given --glc.checkpoint, every gaze source the arms need

The options themselves (ranges, names, `--train.gaze.layers` against the policy's depth) are checked when the
configuration is built (`gazereg.runtime.config.Validated`); `gazereg eval` checks its tasks and checkpoints
the same way (`gazereg.evaluation.rollout.preflight`).
"""

from __future__ import annotations

from pathlib import Path

from gazereg.envs.base import make_collector
from gazereg.evaluation.config import check_tasks
from gazereg.experiment.arms import PriorSpec, arm_prior, gaze_prior
from gazereg.experiment.config import ExperimentConfig
from gazereg.gaze.glc.checkpoint import read_state_dict
from gazereg.gaze.sources import make_gaze_source
from gazereg.gaze.sources.glc import GLCParams, load_glc_model
from gazereg.gaze.sources.glc_folds import GLCFoldsParams
from gazereg.runtime.errors import UsageError, one_line
from gazereg.training.init_from import read_init


def preflight(cfg: ExperimentConfig) -> None:
    """Check before the first stage (UsageError, one line naming the option): the tasks against the
    simulator's registry, `--train.data.tasks` against them (as the store names them), a given
    `--glc.checkpoint` when a prior is made from it (loaded: a missing file, one that is no GLC checkpoint,
    pickled code; a run of other arms does not need it), and every gaze
    source the arms' priors need (built; the glc arm's own GLC and cross-fitted ones are trained later)."""
    check_tasks(cfg.env, cfg.tasks, "--tasks")
    if cfg.train.data.tasks:
        collector = make_collector(cfg.env)
        stored = sorted({collector.episode_task(t) for t in cfg.tasks})
        unknown = [t for t in cfg.train.data.tasks if t not in stored]
        if unknown:
            raise UsageError(
                f"--train.data.tasks: {unknown[0]!r} is not one of the experiment's tasks ({', '.join(stored)})"
            )
    if cfg.train.init_from is not None:  # a saved policy of this type; the train stage checks its shapes
        read_init(Path(cfg.train.init_from), cfg.train.policy.type, "--train.init-from")
    if cfg.glc.checkpoint is not None and needs_glc(cfg):
        check_glc_checkpoint(cfg.glc)
    for prior in priors_to_check(cfg):
        try:
            make_gaze_source(prior.source)
        except (UsageError, ValueError, KeyError, ImportError, OSError) as e:
            raise UsageError(
                f"prior {prior.name!r} (gaze source {prior.source.name}): {one_line(e)}"
            ) from None


def priors_to_check(cfg: ExperimentConfig) -> list[PriorSpec]:
    """The priors the priors stage makes whose source can be built now: all but the glc arm's (a given
    checkpoint is checked on its own; a GLC the experiment trains does not exist yet)."""
    specs = {gaze_prior(cfg).name: gaze_prior(cfg)}
    for prior in arm_priors(cfg):
        if not from_glc(prior):
            specs[prior.name] = prior
    return list(specs.values())


def needs_glc(cfg: ExperimentConfig) -> bool:
    """Whether a prior the priors stage makes comes from a GLC (the glc arm's, or a GLC gaze source)."""
    return any(from_glc(prior) for prior in (gaze_prior(cfg), *arm_priors(cfg)))


def arm_priors(cfg: ExperimentConfig) -> list[PriorSpec]:
    """The prior of every arm that trains with one, in the arms' order."""
    return [prior for arm in cfg.arms if (prior := arm_prior(arm, cfg)) is not None]


def from_glc(prior: PriorSpec) -> bool:
    return isinstance(prior.source, GLCParams | GLCFoldsParams)


def check_glc_checkpoint(params: GLCParams, flag: str = "--glc.checkpoint") -> None:
    """Load the GLC that `params.checkpoint` names (as the priors stage will); a file or folder that does not
    exist, is no GLC checkpoint (of `params.config`) or holds pickled code is a UsageError naming `flag`. A
    file is read before the model is built to compare it with (seconds for the full GLC)."""
    path = str(params.checkpoint)
    try:
        if Path(path).expanduser().is_file():
            read_state_dict(Path(path).expanduser())
        load_glc_model(params.checkpoint, params.config, params.seed)
    except (UsageError, FileNotFoundError) as e:
        message = one_line(e)
        raise UsageError(
            f"{flag} {message}" if message.startswith(path) else f"{flag} {path}: {message}"
        ) from None
