"""The experiment presets of the simulators other than Meta-World: LIBERO-Spatial (`libero`, its toy-size
`libero_smoke`), LIBERO-Object (`libero_object`), LIBERO-Goal (`libero_goal`), LIBERO-10 (`libero_10`) and Gym-Aloha
(`aloha`). Each runs in its simulator's lane
(scripts/libero_env.sh, scripts/aloha_lane.sh); they register in `gazereg.experiment.config.PRESETS` when this module is imported
(the package's __init__ does), so `--preset NAME` finds them like the others.
"""

from __future__ import annotations

import dataclasses
from dataclasses import replace
from pathlib import Path

from gazereg.evaluation.config import presets as eval_presets
from gazereg.experiment.config import PRESETS, ExperimentConfig
from gazereg.gaze.sources.glc import GLCParams
from gazereg.training.config import GazeConfig
from gazereg.training.config import ci as ci_train
from gazereg.training.config import cpu as cpu_train


def libero_suite(eval_preset: str, out: Path) -> ExperimentConfig:
    """The LIBERO experiment over the 10 tasks of the evaluation budget `eval_preset` (`libero-spatial-25`,
    `libero-object-25`): baseline, gaze (visuomotor), cross-fitted glc, uniform (the generic-regularization
    control of the paper's table) and perturbed gaze (the shuffled prior), one training seed, the
    agentview camera at 128 px (patches of 16 px: the 8 x 8 grid of the other presets), evaluated on initial
    states 25..49 clean, and on the first 5 of them per task dimmed (`dim:0.7`) and with sensor noise
    (`gaussian_noise:0.5`): 250 pairs per arm clean, 50 per perturbed condition.

    Demonstrations: the suite's expert on initial states 0..24 only (`demo_max_failures=0`: a failure is not
    replaced by a state the evaluation uses), each of at most the evaluation's episode length; a task keeps
    fewer where the expert fails, and the report counts them. glc: two fold GLCs (tasks 0-4 and 5-9), each
    trained 300 steps on the other half's demonstrations, so no task's glc prior comes from a GLC that saw its
    gaze. Success-versus-steps is not evaluated (`convergence_points=1`): a curve would cost another
    evaluation per checkpoint. Float32 on every CPU (`gazereg sittings` runs a suite's seeds on whichever CPU a
    session gets; `auto` would make some sittings bf16)."""
    ev = eval_presets()[eval_preset]()
    tasks = ev.tasks
    t = cpu_train()
    return ExperimentConfig(
        out=out,
        env="libero",
        tasks=tasks,
        camera="agentview_rgb",
        image_size=128,
        demos_per_task=ev.seed_start,  # the initial states below the evaluation's first
        demo_max_failures=0,
        demo_max_steps=ev.max_steps,  # a demonstration may take as long as an evaluation episode
        heldout_per_task=2,
        arms=("baseline", "gaze", "glc", "uniform", "perturbed"),
        glc_steps=300,
        glc_folds=(tasks[: len(tasks) // 2], tasks[len(tasks) // 2 :]),
        train=replace(
            t,
            steps=6000,
            batch_size=32,
            policy=dataclasses.replace(t.policy, image_hw=(128, 128), patch_size=16),
            mixed_precision="no",
        ),
        parallel=2,
        eval=replace(
            ev, conditions=("clean", "dim:0.7", "gaussian_noise:0.5"), robustness_episodes=5, videos=1
        ),
        convergence_points=1,
        convergence_episodes=ev.episodes,
    )


def libero() -> ExperimentConfig:
    """LIBERO-Spatial, the paper's benchmark (`bash scripts/libero_env.sh gazereg experiment --preset libero`):
    `libero_suite` over its 10 tasks (the evaluation budget `libero-spatial-25`, 220 steps), demonstrations
    by `SpatialExpert`. Why 220 steps, and the time on 2 cores: docs/presets.md."""
    return libero_suite("libero-spatial-25", Path("runs/libero"))


def libero_object() -> ExperimentConfig:
    """LIBERO-Object (`bash scripts/libero_env.sh gazereg experiment --preset libero_object`): `libero_suite`
    over its 10 tasks, an item into the basket (the evaluation budget `libero-object-25`, 280 steps),
    demonstrations by `ObjectExpert` (its success per task: docs/benchmarks/libero_object_expert.json)."""
    return libero_suite("libero-object-25", Path("runs/libero_object"))


def libero_goal() -> ExperimentConfig:
    """LIBERO-Goal (`bash scripts/libero_env.sh gazereg experiment --preset libero_goal`): `libero_suite` over
    its 10 tasks, one kitchen scene with ten goals (the evaluation budget `libero-goal-25`, 300 steps),
    demonstrations by `GoalExpert` (its success per task, and the task it often fails:
    docs/benchmarks/libero_goal_expert.json, docs/libero-goal.md)."""
    return libero_suite("libero-goal-25", Path("runs/libero_goal"))


def libero_10() -> ExperimentConfig:
    """LIBERO-10 (`bash scripts/libero_env.sh gazereg experiment --preset libero_10`): `libero_suite` over its 10
    long-horizon tasks, goals of two or three conjuncts (the evaluation budget `libero-10-25`, 520 steps),
    demonstrations by `LongExpert` (its success per task, and the tasks it fails:
    docs/benchmarks/libero_10_expert.json, docs/libero-10.md). The expert never puts the mug in the microwave
    (`libero_10/9`: no success on initial states 0..24), so that task has no demonstration: it is evaluated like
    the others, the paper's row being over ten tasks, and never trained on (`tasks_without_demos`)."""
    return replace(libero_suite("libero-10-25", Path("runs/libero_10")), tasks_without_demos=("libero_10/9",))


def libero_smoke() -> ExperimentConfig:
    """Every stage of the `libero` preset at toy size (the slow test tests/envs/test_libero_experiment.py, in
    the LIBERO venv): 2 tasks, 2 demonstrations each, 4 training steps, 2 evaluation episodes of 10 steps."""
    ev = eval_presets()["libero-spatial-25"]()
    tasks = ev.tasks[:2]
    return replace(
        libero(),
        out=Path("runs/libero_smoke"),
        tasks=tasks,
        image_size=48,
        demos_per_task=2,
        heldout_per_task=1,
        collect_workers=1,
        prior_size=(32, 32),
        glc=GLCParams(hop=8),
        glc_steps=2,
        glc_folds=((tasks[0],), (tasks[1],)),
        train=replace(ci_train(), steps=4, gaze=GazeConfig(weight=0.1)),
        parallel=1,
        eval=replace(
            ev,
            tasks=tasks,
            episodes=2,
            robustness_episodes=1,
            max_steps=10,
            workers=1,
            conditions=("clean", "dim:0.7", "gaussian_noise:0.5"),
        ),
        convergence_episodes=1,
        figure_frames=2,
    )


def aloha() -> ExperimentConfig:
    """Gym-Aloha, the paper's bimanual benchmark (`bash scripts/aloha_lane.sh gazereg experiment --preset
    aloha`): transfer cube and insertion from the `top` camera at 128 px (patches of 16 px), baseline, gaze
    (visuomotor: the eyes lead each hand to its next target, cube then hand-over point; peg, socket, then the
    meeting point), the controls same_task (another demonstration of the same task's gaze: its phases and the
    fixed meeting point, the objects where that episode had them) and perturbed (the episode's own gaze, its
    blocks shuffled), and the uniform control, one training seed; 50 scripted demonstrations per task on setups
    0..49 (failed ones replaced from 50..69), 50 unseen evaluation episodes per task (setups 1000..1049) of the
    env's 400 steps clean (the evaluation budget `aloha-50`), and the first 25 of them per task dimmed
    (`dim:0.7`) and with sensor noise (`gaussian_noise:0.5`), the paper's robustness axes; float32 on every CPU
    (as the LIBERO suites). The recipe is the one scripts/tune_aloha.py chose without gaze on validation
    setups (docs/tuning/aloha.md): actions predicted in chunks of 50 (one second at 50 Hz), the first 25
    executed open loop, instead of LIBERO's chunk of 4 re-predicted every step."""
    ev, t = eval_presets()["aloha-50"](), cpu_train()
    policy = dataclasses.replace(t.policy, image_hw=(128, 128), patch_size=16, chunk=50, n_action_steps=25)
    return ExperimentConfig(
        out=Path("runs/aloha"),
        env="aloha",
        tasks=ev.tasks,
        camera="top",
        image_size=128,
        demos_per_task=50,
        demo_max_failures=20,
        heldout_per_task=2,
        arms=("baseline", "gaze", "same_task", "perturbed", "uniform"),
        train=replace(
            t,
            steps=6000,
            batch_size=32,
            policy=policy,
            device="auto",
            mixed_precision="no",
        ),
        parallel=2,
        eval=replace(
            ev, conditions=("clean", "dim:0.7", "gaussian_noise:0.5"), robustness_episodes=25, videos=1
        ),
        convergence_points=1,
        convergence_episodes=ev.episodes,
    )


PRESETS.update(
    {
        "libero": libero,
        "libero_object": libero_object,
        "libero_goal": libero_goal,
        "libero_10": libero_10,
        "libero_smoke": libero_smoke,
        "aloha": aloha,
    }
)
