"""The arms an experiment can train, as registered roles: each arm's prior, what its gaze term supervises and
whether the report treats it as a control of the gaze arm.

    arm("perturbed")                    # Arm(name="perturbed", prior=..., target="attention", control=True)
    arm_names()                         # ('baseline', 'gaze', 'perturbed', ...) and installed plugins
    gaze_controls(("baseline", "gaze", "perturbed"))   # ('perturbed',): the report's gaze-vs-control tests
    register_arm(Arm("mine", prior=lambda cfg, names: PriorSpec("uniform", UniformParams()), control=True))

A new arm or control is one registration: `gazereg experiment --arms NAME` accepts it (checked when the
configuration is built), the priors stage makes its prior, the train stage sets its gaze target, and the
report tests the gaze arm against it when `control` is set. Registered in code, an arm exists in the process
that registers it (the experiment's planning, priors and report run there; its training processes receive
finished configurations). An installed package ships one through the entry-point group `gazereg.arms`
(`myarm = "my_package.arms:ARM"`, an `Arm` named `myarm`; see `gazereg.runtime.plugins`).

`prior(cfg, task_names)` reads an experiment configuration (`ArmContext`: the fields of
`gazereg.experiment.config.ExperimentConfig` the built-in arms read) and returns the `PriorSpec` the arm trains
on, or None (the baseline: no gaze term). Cross-fitted GLC (`ExperimentConfig.glc_folds`): the tasks are split
into folds; the GLC of fold k trains on the gaze source's points of the training demonstrations of every other
fold's tasks and predicts the glc prior of fold k's tasks, so no episode's glc prior comes from a GLC that saw
that task's gaze.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol

from gazereg.gaze.sources import GazeSourceParams
from gazereg.gaze.sources.glc import GLCParams
from gazereg.gaze.sources.glc_folds import GLCFoldsParams, inference_settings
from gazereg.gaze.sources.perturbed import PerturbedParams
from gazereg.gaze.sources.simple import SaliencyParams, UniformParams
from gazereg.runtime import plugins
from gazereg.runtime.errors import UsageError
from gazereg.training.config import GAZE_TARGETS, GazeTarget


class UnknownArm(UsageError, KeyError):
    """An arm nobody registered or installed (a user mistake: `gazereg` exits 2 naming the known ones)."""

    __str__ = BaseException.__str__


@dataclass(frozen=True)
class PriorSpec:
    """A prior an arm trains on: its name in the episode store and the gaze source that makes it."""

    name: str
    source: GazeSourceParams


class ArmContext(Protocol):
    """What an arm's prior reads of an experiment configuration."""

    out: Path
    tasks: tuple[str, ...]
    arms: tuple[str, ...]
    gaze: GazeSourceParams
    glc: GLCParams
    glc_folds: tuple[tuple[str, ...], ...]


PriorFn = Callable[[ArmContext, Mapping[str, str] | None], PriorSpec | None]


@dataclass(frozen=True)
class Arm:
    """One arm's role. name: `--arms NAME`; prior: (experiment config, each task's name in the episode store
    or None) -> the prior it trains on, None for no gaze term; target: what its gaze term supervises
    (`GazeConfig.target`: "attention", or "features" for a training-only head); control: the report tests the
    gaze arm against it (paired, like every arm against the baseline); description: one line for listings."""

    name: str
    prior: PriorFn
    target: GazeTarget = "attention"
    control: bool = False
    description: str = ""

    def __post_init__(self) -> None:
        if not self.name or not isinstance(self.name, str):
            raise ValueError(f"an arm needs a name, got {self.name!r}")
        if self.target not in GAZE_TARGETS:
            raise ValueError(f"arm {self.name!r}: target must be one of {GAZE_TARGETS}, got {self.target!r}")


_ARMS: dict[str, Arm] = {}


def register_arm(new: Arm) -> Arm:
    """Register `new` under its name; registering an equal arm again is a no-op, another under a taken name a
    ValueError. Returns it."""
    if not isinstance(new, Arm):
        raise TypeError(f"{new!r} is not a gazereg.training.arms.Arm")
    known = _ARMS.get(new.name)
    if known is not None and known != new:
        raise ValueError(f"arm {new.name!r} is already registered ({known.description or known.prior})")
    _ARMS[new.name] = new
    return new


def unregister_arm(name: str) -> None:
    _ARMS.pop(name, None)


def arm_names() -> tuple[str, ...]:
    """The registered arms in registration order, then those installed plugins provide."""
    extra = [n for n in plugins.plugin_names(plugins.ARMS) if n not in _ARMS]
    return (*_ARMS, *extra)


def arm(name: str) -> Arm:
    """The registered arm `name`, else the installed plugin of that name (registered on first use);
    UnknownArm names the known ones."""
    if name not in _ARMS and (found := plugins.load_plugin(plugins.ARMS, name, "arm")) is not None:
        if not isinstance(found, Arm) or found.name != name:
            value = plugins.plugin_value(plugins.ARMS, name)
            raise TypeError(
                f"{plugins.where(plugins.ARMS, name, value, 'arm')} names {found!r}; it must name a "
                f"gazereg.training.arms.Arm called {name!r}"
            )
        register_arm(found)
    if name not in _ARMS:
        raise UnknownArm(f"unknown arm {name!r}; choose from {', '.join(arm_names())}")
    return _ARMS[name]


def gaze_controls(arms: Iterable[str] | None = None) -> tuple[str, ...]:
    """The gaze arm's controls in registration order: of `arms` (each looked up, plugins loaded), or of every
    registered arm when None."""
    wanted = None if arms is None else {arm(a).name for a in arms}
    return tuple(a.name for a in _ARMS.values() if a.control and (wanted is None or a.name in wanted))


# ----- the built-in arms' priors ------------------------------------------------------------------------------
def trains_glc(cfg: ArmContext) -> bool:
    """Whether the experiment trains its own GLC (one, or one per fold): the glc arm runs and no checkpoint
    was given."""
    return "glc" in cfg.arms and cfg.glc.checkpoint is None


def glc_dir(cfg: ArmContext) -> Path:
    return Path(cfg.out) / "glc"


def glc_fold_dir(cfg: ArmContext, fold: int) -> Path:
    """Where the GLC that predicts the tasks of `cfg.glc_folds[fold]` trains."""
    return glc_dir(cfg) / f"fold{fold}"


def fold_tasks(cfg: ArmContext, fold: int) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(the tasks the GLC of `fold` trains on, the tasks it predicts), both in `cfg.tasks`' order."""
    predicts = cfg.glc_folds[fold]
    return tuple(t for t in cfg.tasks if t not in predicts), tuple(t for t in cfg.tasks if t in predicts)


def glc_folds_source(cfg: ArmContext, task_names: Mapping[str, str] | None = None) -> GLCFoldsParams:
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


def gaze_prior(cfg: ArmContext, _: Mapping[str, str] | None = None) -> PriorSpec:
    """The gaze source's own prior: the gaze arm trains on it, the perturbed controls are made from it and
    every arm's attention is measured against it."""
    return PriorSpec(cfg.gaze.name, cfg.gaze)


def _glc_prior(cfg: ArmContext, task_names: Mapping[str, str] | None) -> PriorSpec:
    if cfg.glc_folds:
        return PriorSpec("glc", glc_folds_source(cfg, task_names))
    trained = replace(cfg.glc, checkpoint=glc_dir(cfg) / "final")
    return PriorSpec("glc", trained if trains_glc(cfg) else cfg.glc)


def _perturbed(mode: str, suffix: str) -> PriorFn:
    """The gaze source's prior perturbed by `mode`, named `<gaze source>-<suffix>`."""
    return lambda cfg, _: PriorSpec(
        f"{cfg.gaze.name}-{suffix}", PerturbedParams(mode=mode, base=cfg.gaze.name)
    )


for _arm in (
    Arm("baseline", lambda cfg, _: None, description="no gaze term"),
    Arm("gaze", gaze_prior, description="the gaze source's prior on the attention"),
    Arm(
        "perturbed",
        _perturbed("shuffle", "shuffled"),
        control=True,
        description="the gaze prior's patches shuffled: wrong locations",
    ),
    Arm(
        "location",
        gaze_prior,
        target="features",
        control=True,
        description="the gaze prior predicted by a training-only head from the image features, not the "
        "attention: the location information without attention supervision",
    ),
    Arm(
        "uniform",
        lambda cfg, _: PriorSpec("uniform", UniformParams()),
        control=True,
        description="a uniform prior: the term without any location",
    ),
    Arm(
        "other_episode",
        _perturbed("other_episode", "other-episode"),
        control=True,
        description="another demonstration's gaze",
    ),
    Arm(
        "same_task",
        _perturbed("same_task", "same-task"),
        control=True,
        description="another demonstration of the same task's gaze: the task's region, not the episode's",
    ),
    Arm(
        "blobs", lambda cfg, _: PriorSpec("blobs", PerturbedParams(mode="blobs")), description="random blobs"
    ),
    Arm("saliency", lambda cfg, _: PriorSpec("saliency", SaliencyParams()), description="image saliency"),
    Arm("glc", _glc_prior, description="a GLC's gaze predicted from the video"),
):
    register_arm(_arm)
del _arm
