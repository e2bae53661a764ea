"""The experiment's configuration and its named presets on Meta-World (smoke, quick, paper, sweep, full; the
other simulators' presets, libero, libero_smoke and aloha, are in `config_sims`, all in one `PRESETS`). Other commands' presets have names of their own kind (training recipes, evaluation and
collection budgets, policy and GLC sizes); `gazereg presets` lists them all. What the presets cost and what
they were sized from (measured): docs/presets.md.

An `ExperimentConfig` checks its options when it is built, its nested `train` and `eval` configs theirs
(`gazereg.runtime.config.Validated`): a bad value is a UsageError naming the option as typed, e.g.
`--arms: unknown arm 'nosuch'; choose from ...` or `--eval.episodes must be an integer >= 1, got 0`.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

from gazereg.aggregation import AggregationConfig
from gazereg.envs.base import SimulatorName, check_simulator
from gazereg.envs.metaworld.difficulty import draw_tasks
from gazereg.evaluation.config import ROBUSTNESS_CONDITIONS, EvalConfig
from gazereg.gaze.sources.glc import GLCParams
from gazereg.gaze.sources.visuomotor import VisuomotorParams
from gazereg.runtime.config import Validated, option, require_entries, require_number
from gazereg.runtime.errors import UsageError
from gazereg.training.arms import UnknownArm, arm
from gazereg.training.config import DataConfig, GazeConfig, OptimConfig, TrainConfig
from gazereg.training.config import ci as ci_train
from gazereg.training.config import cpu as cpu_train
from gazereg.training.config import tuned as tuned_train


@dataclass(frozen=True)
class ExperimentConfig(Validated):
    out: Path = Path("runs/experiment")
    env: SimulatorName = "metaworld"
    """the simulator of the demonstrations and the evaluation, a registered name
    (`gazereg.envs.base.simulator_names()`; `eval.env` must name the same); libero runs in the LIBERO venv
    (scripts/libero_env.sh)"""
    tasks: tuple[str, ...] = ("reach-v3", "button-press-topdown-v3")
    camera: str = "corner2"
    image_size: int = 96
    """side of the square camera images the demonstrations store (pixels)"""
    demos_per_task: int = 30
    """expert demonstrations per task, on setups 0..demos_per_task-1"""
    tasks_without_demos: tuple[str, ...] = ()
    """tasks of `tasks` the expert cannot demonstrate (its measured record says so): evaluated like the others but
    never trained on, since no collection (training, held-out or GLC) runs them; the report counts them apart"""
    demo_max_failures: int = 20
    """extra setups per task (seeds demos_per_task ..) tried in place of the expert's failed rollouts; with 0
    the demonstrations stay on setups 0..demos_per_task-1 and a task keeps fewer where the expert fails (the
    demos stage and the report give the count per task)"""
    demo_max_steps: int = 0
    """a demonstration that has not succeeded after this many steps is a failure (0: the simulator's default,
    `Collector.default_max_steps`)"""
    heldout_per_task: int = 3
    """expert episodes per task on unseen setups, for attention-gaze alignment only"""
    heldout_seed_start: int | None = None
    """the held-out episodes' first setup seed (None: the evaluation's first + `demos.HELDOUT_OFFSET`); a run
    validated on setups the expert cannot solve takes its held-out episodes where it can"""
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
    """optimizer steps of each GLC the experiment trains"""
    glc_folds: tuple[tuple[str, ...], ...] = ()
    """cross-fitted GLC: groups of `tasks` (each task in one); the GLC of a group trains on the training
    demonstrations of every other group's tasks and predicts this group's glc priors, so no episode's prior
    comes from a GLC that saw its task's gaze (no GLC demonstrations are collected); empty = one GLC trained on
    the GLC demonstrations of every task (`glc_demos_per_task`). On the command line a preset's groups are
    changed one by one: --glc-folds.0 TASK ... --glc-folds.1 TASK ..."""
    prior_size: tuple[int, int] = (64, 64)
    aggregation: AggregationConfig = field(default_factory=lambda: AggregationConfig(past=2, future=2))
    arms: tuple[str, ...] = ("baseline", "gaze", "perturbed")
    train_seeds: tuple[int, ...] = (0,)
    train: TrainConfig = field(default_factory=cpu_train)
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
        for name in self.arms:
            try:
                arm(name)
            except UnknownArm as e:
                raise UsageError(f"{option(prefix + 'arms')}: {e}") from None
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
        require_number(self.demo_max_failures, prefix + "demo_max_failures", 0, integer=True)
        if self.heldout_seed_start is not None:
            require_number(self.heldout_seed_start, prefix + "heldout_seed_start", 0, integer=True)
        require_number(self.demo_max_steps, prefix + "demo_max_steps", 0, integer=True)
        if not self.camera:
            raise UsageError(f"{option(prefix + 'camera')} is empty: name the camera")
        check_simulator(self.env, option(prefix + "env"))
        if self.eval.env != self.env:
            raise UsageError(
                f"{option(prefix + 'eval.env')} {self.eval.env} differs from {option(prefix + 'env')} "
                f"{self.env}: the evaluation runs in the demonstrations' simulator; set both"
            )
        self.validate_untrained(prefix)
        self.validate_folds(prefix)

    @property
    def demo_tasks(self) -> tuple[str, ...]:
        """`tasks` that have demonstrations: every one but `tasks_without_demos`, in order."""
        return tuple(t for t in self.tasks if t not in self.tasks_without_demos)

    def validate_untrained(self, prefix: str) -> None:
        """`tasks_without_demos`: tasks of `tasks`, not all of them, and no fold of `glc_folds` made of them only."""
        flag = option(prefix + "tasks_without_demos")
        unknown = [t for t in self.tasks_without_demos if t not in self.tasks]
        if unknown:
            raise UsageError(f"{flag}: {unknown} are not in {option(prefix + 'tasks')}")
        if not self.demo_tasks:
            raise UsageError(f"{flag} names every task: nothing would be trained on")
        bare = [fold for fold in self.glc_folds if fold and not set(fold) - set(self.tasks_without_demos)]
        if bare:
            raise UsageError(
                f"{flag}: the glc fold {list(bare[0])} has no task with demonstrations, so no episode to score its GLC on"
            )

    def validate_folds(self, prefix: str) -> None:
        """`glc_folds`: at least two non-empty groups that split `tasks`, and no GLC checkpoint given."""
        if not self.glc_folds:
            return
        flag = option(prefix + "glc_folds")
        listed = [t for fold in self.glc_folds for t in fold]
        if len(self.glc_folds) < 2 or not all(self.glc_folds):
            raise UsageError(f"{flag} takes at least two non-empty groups of tasks, got {self.glc_folds}")
        require_entries(listed, prefix + "glc_folds", show=str)
        if set(listed) != set(self.tasks):
            unknown, missing = (
                sorted(set(listed) - set(self.tasks)),
                [t for t in self.tasks if t not in listed],
            )
            raise UsageError(
                f"{flag} must split {option(prefix + 'tasks')} into groups, each task in one: "
                f"not tasks: {unknown or 'none'}; in no group: {missing or 'none'}"
            )
        if self.glc.checkpoint is not None:
            raise UsageError(
                f"{flag} trains a GLC per group; {option(prefix + 'glc.checkpoint')} gives one: choose one"
            )


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


# ----- presets ------------------------------------------------------------------------------------------------
def quick() -> ExperimentConfig:
    """From scratch, the main job before `demo`: baseline against gaze on reach-v3 and button-press-topdown-v3, 50
    demonstrations per task, one training seed, 5,000 steps of batch 32 (bf16 where the CPU has it), 25 unseen
    setups per task, clean condition only (robustness is the `paper` preset's job). Why this size, and its
    time: docs/presets.md."""
    return ExperimentConfig(
        out=Path("runs/quick"),
        demos_per_task=50,
        arms=("baseline", "gaze"),
        train=replace(cpu_train(), steps=5000, batch_size=32),
        parallel=2,
        eval=EvalConfig(episodes=25, max_steps=120, conditions=("clean",)),
        convergence_points=2,
        convergence_episodes=10,
    )


def smoke() -> ExperimentConfig:
    """CI: every stage of the pipeline at toy size (reach-v3, 48 px, 3 demonstrations, 12 training steps)."""
    t = ci_train()
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
    """The powered comparison on the headline tasks with the recipe tuned without gaze (`training.config.tuned`):
    baseline, visuomotor gaze, glc gaze (a GLC trained on the simulated gaze of 20 demonstrations per task on
    setups of their own, predicting from video only), shuffled gaze (`perturbed`) and the location control
    (the prior supervising a head on the features, not attention) x 3 seeds; 50 unseen setups per task and
    condition (clean, dim, noise), paired across arms; checkpoints every 2,000 steps. Too long for one sitting
    on 2 cores, it runs one seed per folder (5 runs at once), then one report (`gazereg.experiment.pool`):
        gazereg experiment --preset paper --train-seeds 0 --out runs/paper-s0
        gazereg experiment --preset paper --train-seeds 1 --out runs/paper-s1 --data-from runs/paper-s0  # and 2
        gazereg pool --preset paper --runs runs/paper-s0 runs/paper-s1 runs/paper-s2 --out runs/paper"""
    return ExperimentConfig(
        out=Path("runs/paper"),
        demos_per_task=50,
        heldout_per_task=5,
        arms=("baseline", "gaze", "glc", "perturbed", "location"),
        train_seeds=(0, 1, 2),
        train=replace(tuned_train(), device="auto"),  # a GPU when there is one
        parallel=5,
        eval=EvalConfig(episodes=50, max_steps=120, conditions=("clean", "dim:0.7", "gaussian_noise:0.5")),
        convergence_points=8,
        convergence_episodes=10,
    )


SWEEP_DRAW = {"easy": 4, "medium": 2, "hard": 2}
"""the task sweep's tasks per LeRobot difficulty group (gazereg.envs.metaworld.difficulty)"""


def sweep() -> ExperimentConfig:
    """More tasks, fixed before any result was seen: 4 easy, 2 medium and 2 hard Meta-World tasks drawn at
    random from LeRobot's difficulty groups without the two headline tasks (`draw_tasks(SWEEP_DRAW,
    exclude=quick().tasks, seed=0)`: faucet-open, window-close, handle-press-side, button-press; coffee-push,
    soccer; pick-place, push), trained together with the `paper` preset's recipe (one seed); baseline,
    visuomotor gaze, cross-fitted glc (two GLCs, each trained on the other four tasks' demonstrations, 2 easy,
    1 medium and 1 hard each: no task's prior comes from a GLC that saw its gaze) and the location control; 50
    unseen setups per task, clean. Its time: docs/presets.md."""
    tasks = draw_tasks(SWEEP_DRAW, exclude=quick().tasks, seed=0)
    return ExperimentConfig(
        out=Path("runs/sweep"),
        tasks=tasks,
        demos_per_task=50,
        arms=("baseline", "gaze", "glc", "location"),
        glc_folds=(tasks[0:2] + tasks[4:5] + tasks[6:7], tasks[2:4] + tasks[5:6] + tasks[7:8]),
        train=paper().train,
        parallel=2,
        eval=EvalConfig(episodes=50, max_steps=120, conditions=("clean",)),
        convergence_points=1,
        convergence_episodes=10,
    )


def full() -> ExperimentConfig:
    """The wider study for a many-core machine with a GPU: 5 tasks at 128 px, every gaze-source ablation arm,
    3 seeds x 20,000 steps, the full lighting and noise sweep (evaluate.ROBUSTNESS_CONDITIONS), 50 episodes per task and condition."""
    t = cpu_train()
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


PRESETS = {
    "quick": quick,
    "smoke": smoke,
    "paper": paper,
    "full": full,
    "sweep": sweep,
}
"""every experiment preset by name: these, the other simulators' (`config_sims`: libero, libero_smoke, aloha)
and the pretraining study's (`config_finetune`), which register themselves here when the package is imported"""

DEFAULT_PRESET = "demo"
"""`gazereg experiment`'s preset without `--preset`: the main job, `make demo` (registered by `config_finetune`);
`gazereg pool` has none (it takes the preset the pooled runs were made with)"""
