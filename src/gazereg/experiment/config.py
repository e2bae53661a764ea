"""The experiment's configuration: what an arm is, and the named presets (smoke, quick, paper, full).

An `ExperimentConfig` checks its options when it is built, its nested `train` and `eval` configs theirs
(`gazereg.runtime.config.Validated`): a bad value is a UsageError naming the option as typed, e.g.
`--arms: unknown arm 'nosuch'; choose from ...` or `--eval.episodes must be an integer >= 1, got 0`.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

from gazereg.evaluation.config import ROBUSTNESS_CONDITIONS, EvalConfig
from gazereg.gaze.aggregation import AggregationConfig
from gazereg.gaze.sources import GazeSourceParams
from gazereg.gaze.sources.glc import GLCParams
from gazereg.gaze.sources.perturbed import PerturbedParams
from gazereg.gaze.sources.simple import SaliencyParams, UniformParams
from gazereg.gaze.sources.visuomotor import VisuomotorParams
from gazereg.report.build import ReportSpec
from gazereg.runtime.config import Validated, option, require_entries, require_number, to_dict
from gazereg.runtime.errors import UsageError
from gazereg.training.config import DataConfig, GazeConfig, OptimConfig, TrainConfig
from gazereg.training.config import quick as quick_train
from gazereg.training.config import smoke as smoke_train


@dataclass(frozen=True)
class ExperimentConfig(Validated):
    out: Path = Path("runs/experiment")
    tasks: tuple[str, ...] = ("reach-v3", "button-press-topdown-v3")
    camera: str = "corner2"
    image_size: int = 96
    demos_per_task: int = 30
    """expert demonstrations per task, on setups 0..demos_per_task-1"""
    heldout_per_task: int = 3
    """expert episodes per task on unseen setups, for attention-gaze alignment only"""
    collect_workers: int = 2
    gaze: VisuomotorParams = field(default_factory=VisuomotorParams)
    """the gaze arm's source, simulated eye-hand coordination on the demonstrations' simulator facts: its
    perturbed controls are made from it, GLC learns from it, and every arm's attention is measured against it"""
    glc: GLCParams = field(default_factory=GLCParams)
    """the `glc` arm's gaze source; without a checkpoint a small GLC is trained here first (see `trains_glc`) on
    the gaze source's points of other demonstrations, then predicts the priors"""
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

    def validate(self, prefix: str) -> None:
        """UsageError naming the first bad option (the nested train and eval configs check their own)."""
        for name in ("tasks", "arms", "train_seeds"):
            require_entries(getattr(self, name), prefix + name, show=str)
        unknown = [a for a in self.arms if a not in ARMS]
        if unknown:
            raise UsageError(
                f"{option(prefix + 'arms')}: unknown arm {unknown[0]!r}; choose from {', '.join(ARMS)}"
            )
        for seed in self.train_seeds:
            require_number(seed, prefix + "train_seeds", integer=True)
        least = {
            "image_size": 8,
            "demos_per_task": 1,
            "heldout_per_task": 1,
            "collect_workers": 0,
            "glc_demos_per_task": 1,
            "glc_steps": 1,
            "parallel": 1,
            "threads_per_run": 1,
            "convergence_points": 1,
            "convergence_episodes": 1,
            "figure_frames": 1,
        }
        for name, low in least.items():
            require_number(getattr(self, name), prefix + name, low, integer=True)
        if len(self.prior_size) != 2:
            raise UsageError(
                f"{option(prefix + 'prior_size')} takes two sizes (height width), got {self.prior_size}"
            )
        for side in self.prior_size:
            require_number(side, prefix + "prior_size", 1, integer=True)
        require_number(self.threshold, prefix + "threshold", 0, 1, open_low=True, open_high=True)
        if not self.camera:
            raise UsageError(f"{option(prefix + 'camera')} is empty: name the camera")


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
    return "glc" in cfg.arms and cfg.glc.checkpoint is None


def glc_dir(cfg: ExperimentConfig) -> Path:
    return Path(cfg.out) / "glc"


@dataclass(frozen=True)
class PriorSpec:
    """A prior an arm trains on: its name in the episode store and the gaze source that makes it."""

    name: str
    source: GazeSourceParams


ARMS = ("baseline", "gaze", "perturbed", "blobs", "other_episode", "saliency", "uniform", "glc")


def gaze_prior(cfg: ExperimentConfig) -> PriorSpec:
    """The gaze source's own prior: the gaze arm trains on it, the perturbed controls are made from it and
    every arm's attention is measured against it."""
    return PriorSpec(cfg.gaze.name, cfg.gaze)


def arm_prior(arm: str, cfg: ExperimentConfig) -> PriorSpec | None:
    """The prior `arm` trains on; None for the baseline."""
    base = cfg.gaze.name
    if arm == "baseline":
        return None
    if arm == "gaze":
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
        trained = replace(cfg.glc, checkpoint=glc_dir(cfg) / "final")
        return PriorSpec("glc", trained if trains_glc(cfg) else cfg.glc)
    raise KeyError(f"unknown arm {arm!r}; choose from {sorted(ARMS)}")


def report_spec(cfg: ExperimentConfig, preset: str) -> ReportSpec:
    """What the report says the experiment ran."""
    return ReportSpec(
        preset=preset,
        tasks=cfg.tasks,
        arms=cfg.arms,
        train_seeds=cfg.train_seeds,
        train_steps=cfg.train.steps,
        batch_size=cfg.train.batch_size,
        gaze_weight=cfg.train.gaze.weight,
        gaze_layers=tuple(cfg.train.gaze.layers),
        eval_episodes=cfg.eval.episodes,
        eval_conditions=tuple(cfg.eval.conditions),
        eval_seed_start=cfg.eval.seed_start,
        convergence_episodes=cfg.convergence_episodes,
        threshold=cfg.threshold,
        config=to_dict(cfg),
    )


# ----- presets ------------------------------------------------------------------------------------------------
def quick() -> ExperimentConfig:
    """The README's main job (`make demo`), sized to detect the gain the `paper` preset measured, in about 12
    minutes on 2 CPU cores: baseline against gaze on reach-v3 and button-press-topdown-v3, 50 demonstrations
    per task, one training seed, 5,000 steps of batch 32 (bf16 where the CPU has it), 25 unseen setups per
    task, clean condition only (robustness is the `paper` preset's job).

    Power: the `paper` preset's gaze-vs-baseline clean comparison had 85 pairs only gaze solved and 8 only
    the baseline solved of 300; `python scripts/power.py --a-only 85 --b-only 8 --pairs 300` gives power
    0.93 for exact McNemar at alpha 0.05 with 50 pairs (0.85 with 40, 0.68 with 30), hence 25 setups x 2
    tasks. Those rates were measured at 8,000 steps with 3 seeds; 5,000 steps is what fits in the time, and
    the paper run's checkpoints showed most of the gaze arm's gain by then (docs/results.md, "Training
    budget"), so the power at this size is an estimate, not a promise."""
    return ExperimentConfig(
        out=Path("runs/quick"),
        demos_per_task=50,
        arms=("baseline", "gaze"),
        train=replace(quick_train(), steps=5000, batch_size=32),
        parallel=2,
        eval=EvalConfig(episodes=25, max_steps=120, conditions=("clean",)),
        convergence_points=2,
        convergence_episodes=10,
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
    """The powered comparison sized for this CPU (98 minutes on 2 cores with bf16 training at 5a39472,
    docs/results.md; faster with more cores): the claim's three arms (baseline, gaze, perturbed gaze) x 3
    training seeds, 8,000 steps of batch 32 with checkpoints every 1,000 for the success-versus-steps curve,
    50 unseen setups per task and condition, paired by seed across arms. Resumable stage by stage;
    evaluation resumes episode by episode.

    8,000 steps: on the same setups the gaze arm's clean success rose from 4,000 to 6,000 steps and the
    baseline's from 6,000 to 8,000, and neither rose further (gaze 6,000 -> 8,000, baseline 8,000 -> 10,000;
    docs/results.md, "Training budget"), so a shorter budget shortchanges one arm and a longer one gains nothing."""
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
