"""The experiment's configuration: what an arm is, and the named presets (smoke, quick, paper, full)."""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

from gazereg.evaluation.rollout import ROBUSTNESS_CONDITIONS, EvalConfig
from gazereg.gaze.aggregation import AggregationConfig
from gazereg.training.config import DataConfig, GazeConfig, OptimConfig, TrainConfig
from gazereg.training.config import quick as quick_train
from gazereg.training.config import smoke as smoke_train


@dataclass(frozen=True)
class ExperimentConfig:
    out: Path = Path("runs/experiment")
    tasks: tuple[str, ...] = ("reach-v3", "button-press-topdown-v3")
    camera: str = "corner2"
    image_size: int = 96
    demos_per_task: int = 30
    """expert demonstrations per task, on setups 0..demos_per_task-1"""
    heldout_per_task: int = 3
    """expert episodes per task on unseen setups, for attention-gaze alignment only"""
    collect_workers: int = 2
    gaze_source: str = "visuomotor"
    gaze_params: tuple[str, ...] = ()
    glc_params: tuple[str, ...] = ()
    """the `glc` arm's gaze-source parameters; without checkpoint=DIR a small GLC is trained here first (see
    `trains_glc`) on the gaze source's points of other demonstrations, then predicts the priors"""
    glc_demos_per_task: int = 20
    """expert demonstrations per task on setups of their own (never trained on or evaluated) that train GLC"""
    glc_steps: int = 600
    prior_size: tuple[int, int] = (64, 64)
    aggregation: AggregationConfig = field(default_factory=lambda: AggregationConfig(past=2, future=2))
    arms: tuple[str, ...] = ("baseline", "gaze", "perturbed")
    train_seeds: tuple[int, ...] = (0,)
    train: TrainConfig = field(default_factory=quick_train)
    parallel: int = 2
    """training processes at once (each with threads_per_run threads); as many as runs keeps every core busy
    to the end instead of leaving one run to train alone"""
    threads_per_run: int = 1
    eval: EvalConfig = field(
        default_factory=lambda: EvalConfig(episodes=10, conditions=("clean", "dim:0.7", "gaussian_noise:0.5"))
    )
    convergence_points: int = 3
    """checkpoints along training (the last is the final one) evaluated clean for the success-vs-steps curve"""
    convergence_episodes: int = 10
    threshold: float = 0.5
    """success rate whose first crossing is reported as 'steps to threshold'"""
    figure_frames: int = 4


EXECUTION_KEYS = (
    "parallel",
    "threads_per_run",
    "collect_workers",
    "train.device",
    "train.data.num_workers",
    "train.logger",
    "eval.workers",
    "eval.gl_backend",
)
"""config keys that change how a run executes, not what it measures: a resumed run may change them"""


def trains_glc(cfg: ExperimentConfig) -> bool:
    """Whether the experiment trains its own GLC: the glc arm runs and no checkpoint was given."""
    return "glc" in cfg.arms and not any(p.startswith("checkpoint=") for p in cfg.glc_params)


def glc_dir(cfg: ExperimentConfig) -> Path:
    return Path(cfg.out) / "glc"


def arm_prior(arm: str, cfg: ExperimentConfig) -> tuple[str | None, str | None, tuple[str, ...]]:
    """Arm -> (prior name, gaze source, source params); baseline has none."""
    base = cfg.gaze_source
    table: dict[str, tuple[str | None, str | None, tuple[str, ...]]] = {
        "baseline": (None, None, ()),
        "gaze": (base, base, cfg.gaze_params),
        "perturbed": (f"{base}-shuffled", "perturbed", ("mode=shuffle", f"base={base}")),
        "blobs": ("blobs", "perturbed", ("mode=blobs",)),
        "other_episode": (f"{base}-other-episode", "perturbed", ("mode=other_episode", f"base={base}")),
        "saliency": ("saliency", "saliency", ()),
        "uniform": ("uniform", "uniform", ()),
        "glc": (
            "glc",
            "glc",
            cfg.glc_params if not trains_glc(cfg) else (f"checkpoint={glc_dir(cfg) / 'final'}",),
        ),
    }
    if arm not in table:
        raise KeyError(f"unknown arm {arm!r}; choose from {sorted(table)}")
    return table[arm]


# ----- presets ------------------------------------------------------------------------------------------------
def quick() -> ExperimentConfig:
    """~15 minutes on 2 CPU cores: 2 tasks, 3 arms x 1,000 steps of batch 32, 10 unseen setups per condition."""
    return ExperimentConfig(
        out=Path("runs/quick"),
        train=replace(quick_train(), steps=1000, batch_size=32),
        parallel=3,
        eval=EvalConfig(episodes=10, max_steps=120, conditions=("clean", "dim:0.7", "gaussian_noise:0.5")),
    )


def smoke() -> ExperimentConfig:
    t = smoke_train()
    return ExperimentConfig(
        out=Path("runs/smoke"),
        tasks=("reach-v3",),
        image_size=48,
        demos_per_task=3,
        heldout_per_task=1,
        collect_workers=1,
        prior_size=(32, 32),
        arms=("baseline", "gaze", "perturbed", "glc"),
        glc_demos_per_task=5,
        glc_steps=3,
        train=replace(t, steps=12, gaze=GazeConfig(weight=0.1)),
        parallel=1,
        eval=EvalConfig(episodes=2, max_steps=15, workers=1, videos=1, conditions=("clean", "dim:0.7")),
        convergence_points=2,
        convergence_episodes=1,
        figure_frames=2,
    )


def paper() -> ExperimentConfig:
    """The powered comparison sized for this CPU (2 cores, about two hours; faster with more cores): the
    claim's three arms (baseline, gaze, perturbed gaze) x 3 training seeds, 8,000 steps of batch 32 with
    checkpoints every 1,000 for the success-versus-steps curve, 50 unseen setups per task and condition,
    paired by seed across arms. Resumable stage by stage; evaluation resumes episode by episode.

    8,000 steps: on the same setups the gaze arm's clean success rose from 4,000 to 6,000 steps and the
    baseline's from 6,000 to 8,000, and neither rose further (gaze 6,000 -> 8,000, baseline 8,000 -> 10,000;
    README, "Training budget"), so a shorter budget shortchanges one arm and a longer one gains nothing."""
    return ExperimentConfig(
        out=Path("runs/paper"),
        demos_per_task=50,
        heldout_per_task=5,
        arms=("baseline", "gaze", "perturbed"),
        train_seeds=(0, 1, 2),
        train=replace(quick_train(), steps=8000, batch_size=32, device="auto"),  # a GPU when there is one
        parallel=3,
        eval=EvalConfig(episodes=50, max_steps=120, conditions=("clean", "dim:0.7", "gaussian_noise:0.5")),
        convergence_points=8,
        convergence_episodes=10,
    )


def full() -> ExperimentConfig:
    """The wider study for a many-core machine with a GPU: 5 tasks at 128 px, every gaze-source ablation arm,
    3 seeds x 20,000 steps, the full lighting and noise sweep (evaluate.ROBUSTNESS_CONDITIONS), 50 episodes per task and condition."""
    t = quick_train()
    return ExperimentConfig(
        out=Path("runs/full"),
        tasks=("reach-v3", "button-press-topdown-v3", "pick-place-v3", "drawer-open-v3", "push-v3"),
        image_size=128,
        demos_per_task=50,
        heldout_per_task=5,
        arms=("baseline", "gaze", "perturbed", "blobs", "other_episode", "saliency", "uniform"),
        train_seeds=(0, 1, 2),
        train=replace(
            t,
            steps=20_000,
            policy=dataclasses.replace(t.policy, image_hw=(128, 128), patch_size=16),
            optim=OptimConfig(lr=5e-4, warmup_steps=500, min_lr_frac=0.05),
            data=DataConfig(),
            device="auto",
        ),
        parallel=os.cpu_count() or 2,
        eval=EvalConfig(
            episodes=50,
            max_steps=200,
            workers=os.cpu_count() or 2,
            conditions=ROBUSTNESS_CONDITIONS,
        ),
        convergence_points=8,
        convergence_episodes=20,
    )


PRESETS = {"quick": quick, "smoke": smoke, "paper": paper, "full": full}
