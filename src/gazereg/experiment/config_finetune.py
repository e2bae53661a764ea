"""The experiment presets of the pretraining study (issue 36, docs/pretraining.md): the ML45 generalist
(`gazereg pretrain --preset ml45`, committed in `GENERALIST`) fine-tuned on ML45's five held-out tasks
(`ml45_finetune`), and the same run from a fresh initialisation (`ml45_scratch`); the study's presets
(`ml45_study`, `ml45_study50`) and the README's main job (`demo`, `make demo`), a small fine-tuning of the
generalist. They register in `gazereg.experiment.config.PRESETS` when the package is imported.

    gazereg experiment --preset ml45_scratch  --out runs/ft10-scratch
    gazereg experiment --preset ml45_finetune --out runs/ft10-pretrained
    gazereg compare runs/ft10-scratch runs/ft10-pretrained
    (50 demonstrations per task: --demos-per-task 50)

Both collect the same demonstrations (setups 0.. of the held-out tasks, which the pretraining never saw) and
evaluate on the same unseen setups (1,000..), so `gazereg compare` pairs their episodes; the architecture is
the generalist's (`pretrain_config.ml45_policy`) in both, and so are the training recipe and its budget.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from gazereg.envs.metaworld.ml45 import ml45_split
from gazereg.evaluation.config import EvalConfig
from gazereg.experiment.config import PRESETS, ExperimentConfig
from gazereg.experiment.pretrain_config import GENERALIST, held_out_instructions, ml45_policy
from gazereg.gaze.sources.glc import GLCParams
from gazereg.training.config import GazeConfig
from gazereg.training.config import tuned as tuned_train


def ml45_finetune() -> ExperimentConfig:
    """The generalist (`GENERALIST`) fine-tuned on ML45's 5 held-out tasks: 10 demonstrations per task, the
    baseline arm (no gaze), the tuned recipe's learning rate 5e-4 and batch 32 for 3,000 steps on 2 threads
    (one run), success at 3 checkpoints on 10 setups per task, and finally 25 unseen setups per task of at
    most 200 steps (the experts need up to about 140), clean."""
    t = tuned_train()
    return ExperimentConfig(
        out=Path("runs/ml45-finetune"),
        tasks=ml45_split().test,
        demos_per_task=10,
        arms=("baseline",),
        train=replace(
            t,
            steps=3000,
            batch_size=32,
            policy=ml45_policy(),
            data=replace(t.data, extra_instructions=held_out_instructions()),
            init_from=GENERALIST,
            device="auto",
        ),
        parallel=1,
        threads_per_run=2,
        eval=EvalConfig(episodes=25, max_steps=200, conditions=("clean",)),
        convergence_points=3,
        convergence_episodes=10,
    )


def ml45_scratch() -> ExperimentConfig:
    """`ml45_finetune` from a fresh initialisation instead of the generalist: the same demonstrations,
    architecture, recipe, budget and evaluation setups."""
    ft = ml45_finetune()
    return replace(ft, out=Path("runs/ml45-scratch"), train=replace(ft.train, init_from=None))


GLC_ML45 = Path("runs/glc-ml45/final")
"""The study's GLC: trained on the visuomotor gaze of the 45 training tasks' demonstrations only, never a held-out
task's (`gazereg glc train --store runs/pretrain/demos --gaze-source visuomotor --out runs/glc-ml45`;
docs/pretraining.md); not committed (14 MB), rebuilt by that command"""

STUDY_GAZE = GazeConfig(weight=1e-3, queries="both", layers=(3,))
"""The gaze term the tuning chose on validation setups (docs/tuning/finetune.md, "Chosen"): weight, query set
and layers; every gaze-term arm of the study uses it, the controls at the same weight"""


STUDY_ARMS = ("baseline", "gaze", "glc", "uniform")
"""the study's arms at both demonstration counts"""

STUDY_CONTROLS = ("same_task", "other_episode", "perturbed", "location")
"""the controls that tell the episode's own gaze from any task-region prior, at 10 demonstrations only"""


def ml45_study() -> ExperimentConfig:
    """The fine-tuning study (issue 36 item 4) at 10 demonstrations per task: `ml45_finetune` at the tuned
    recipe (6,000 steps) with the tuned gaze term (`STUDY_GAZE`); arms baseline, gaze (the visuomotor
    prior), glc (`GLC_ML45`'s prediction from the video), uniform (the term without any location), same_task
    (another demonstration of the same task's gaze: the task's region without the episode's locations),
    other_episode (another demonstration's, of any task), perturbed (the episode's own gaze, its blocks
    shuffled: wrong places, same statistics) and location (the same prior predicted by a training-only head
    from the image features: the location information without attention supervision); 3
    training seeds; 50 unseen setups per task (1,000..1,049), clean; success at 3 checkpoints on 10 setups
    per task (convergence). Float32 on every CPU: its sittings run on whichever CPU a session gets, and a
    block's pairs must not differ in precision (`auto` is bf16 on a CPU with native bf16). Two arms a
    sitting, side by side on one thread each: the 2 cores train more steps per second that way than with one
    run on both (benchmarks/bench_parallel.py, docs/speed.md), and eight arms do not fit a session
    (`gazereg sittings ml45-study` runs the sittings, two arms each).

        gazereg experiment --preset ml45_study --train-seeds 0 --arms baseline gaze --out runs/study10-s0
        gazereg experiment --preset ml45_study --train-seeds 0 --arms glc uniform --out runs/study10-s0-glc \
            --data-from runs/study10-s0
        gazereg experiment --preset ml45_study --train-seeds 1 --arms baseline gaze --out runs/study10-s1 \
            --data-from runs/study10-s0
        ...
        gazereg pool --preset ml45_study --runs runs/study10-s0 runs/study10-s0-glc runs/study10-s1 ... \
            --out runs/study10
    """
    ft = ml45_finetune()
    return replace(
        ft,
        out=Path("runs/ml45-study"),
        arms=(*STUDY_ARMS, *STUDY_CONTROLS),
        train_seeds=(0, 1, 2),
        train=replace(ft.train, steps=6000, gaze=STUDY_GAZE, mixed_precision="no"),
        glc=GLCParams(checkpoint=GLC_ML45),
        eval=replace(ft.eval, episodes=50),
        parallel=2,
        threads_per_run=1,
    )


def ml45_study50() -> ExperimentConfig:
    """`ml45_study` with 50 demonstrations per task (the same setups 0.. extended, the same evaluation),
    without the controls that tell the episode's own gaze from any task-region prior (same_task,
    other_episode, perturbed, location): they ask where gaze helps, at 10 demos (issue 36: the other controls
    where gaze differs from the baseline)."""
    return replace(ml45_study(), out=Path("runs/ml45-study50"), demos_per_task=50, arms=STUDY_ARMS)


DEMO_TASKS = ("box-close-v3", "door-unlock-v3")
"""`make demo`'s two held-out tasks: the two whose validation success under the study's baseline recipe (the
tuning's ft-steps6k run, setups 1300..1319, docs/tuning/finetune.md) is nearest one half, ties to the earlier task
in ML45's order: the tasks with the most room for two arms to differ either way. Chosen on validation setups
only; tests/test_finetune_presets.py recomputes the choice from the run's archive."""

DEMO_EVAL_START = 3000
"""`make demo`'s first evaluation setup: its 50 setups per task (and its alignment episodes, 500 on) are used by
no other run on ML45's held-out tasks (the study evaluates from 1,000, the tuning validates from 1,300)"""


def demo() -> ExperimentConfig:
    """The README's main job (`make demo`): the committed generalist (`GENERALIST`) fine-tuned on two of ML45's
    held-out tasks (`DEMO_TASKS`), baseline against gaze (the study's gaze term, `STUDY_GAZE`), with the study's
    recipe and demonstrations (10 per task, learning rate 5e-4, batch 32) but 1,000 steps instead of 6,000, one
    training seed, two arms side by side on one thread each; then 50 unseen setups per task of its own
    (`DEMO_EVAL_START`), clean, and no success-versus-steps curve. Sized to finish within 15 minutes on 2 cores
    of this machine kind's slowest CPU (float32, AVX2 only); docs/main-job.md gives the measured time, and what a
    comparison of this size can detect at the study's own paired rates (`python scripts/power.py --run ...`)."""
    study = ml45_study()
    return replace(
        study,
        out=Path("runs/demo"),
        tasks=DEMO_TASKS,
        arms=("baseline", "gaze"),
        train_seeds=(0,),
        train=replace(study.train, steps=1000),
        glc=GLCParams(),
        eval=replace(study.eval, episodes=50, seed_start=DEMO_EVAL_START),
        convergence_points=1,
    )


PRESETS.update(
    {
        "demo": demo,
        "ml45_finetune": ml45_finetune,
        "ml45_scratch": ml45_scratch,
        "ml45_study": ml45_study,
        "ml45_study50": ml45_study50,
    }
)
