"""`gazereg pretrain`'s configuration, its presets (`ml45`, `ml45_continued`, `toy`) and what it checks before any work.

    cfg = PRESETS["toy"]()                  # 2 tasks, a tiny policy, seconds
    preflight(cfg)                            # tasks, held-out tasks, instructions vs the tokenizer
    finetune_flags(cfg.train.policy)          # ["--train.policy.dim", "192", ...]: the architecture to fine-tune

The options are checked when the config is built (`Validated`): counts in range, the demonstrations' and the
evaluation's setup seeds inside the ranges reserved for pretraining (gazereg.envs.metaworld.setups), no gaze
prior. `preflight` refuses, before any work, a task outside Meta-World, one of ML45's held-out tasks, and a
tokenizer that could not encode an instruction of the pretraining tasks or of the held-out ones.

The tokenizer. The fine-tuning runs encode ML45's held-out instructions with the pretrained tokenizer
(gazereg.training.init_from reuses it), so its vocabulary must hold their words. The presets use the "words"
tokenizer with a vocabulary built from the pretraining tasks' instructions and the held-out tasks' ones
(`--train.data.extra-instructions`; a vocabulary of the 45 training instructions alone maps the held-out
tasks' own words, lock, unlock, bin, lid, hand, ..., to <unk>), at most 13 words, so 16 text tokens. The
held-out tasks' own words keep their initial embeddings until fine-tuning trains them. The "bytes" tokenizer
encodes any text but needs 64 text tokens (the longest ML45 instruction has 58 bytes): `ml45_policy`'s
sequence grows from 89 to 137 tokens, and every training and fine-tuning step pays for them.
`--train.policy.tokenizer bytes --train.policy.max-text-len 64` chooses it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, replace
from pathlib import Path

from gazereg.envs.metaworld.instructions import instruction_for
from gazereg.envs.metaworld.ml45 import ml45_split
from gazereg.envs.metaworld.setups import PRETRAIN_DEMOS, PRETRAIN_EVAL
from gazereg.evaluation.config import check_tasks
from gazereg.policies import PolicyConfig
from gazereg.policies.vla.configuration_vla import VLAConfig
from gazereg.policies.vla.processor_vla import Tokenizer
from gazereg.runtime.config import Validated, option, require_entries, require_number
from gazereg.runtime.errors import UsageError
from gazereg.training.config import EXECUTION_KEYS as TRAIN_EXECUTION_KEYS
from gazereg.training.config import OptimConfig, TrainConfig
from gazereg.training.config import ci as ci_train
from gazereg.training.config import tuned as tuned_train
from gazereg.training.init_from import read_init

GENERALIST = Path("models/ml45")
"""the committed generalist (relative to the repository root): `ml45`'s policy folder (model.safetensors,
config.json, tokenizer.json) with its manifest.json; `ml45_continued` starts from it, the fine-tuning presets
(gazereg.experiment.config_finetune) fine-tune it"""
TEXT_TOKENS = 16
"""word tokens of the presets' instruction: the longest ML45 instruction has 13 words"""


@dataclass(frozen=True)
class PretrainConfig(Validated):
    """Multi-task pretraining with language (no gaze): demos -> train -> eval -> manifest (gazereg.experiment
    .pretrain). The training run's folder, store and gaze settings are the stages' own."""

    out: Path = Path("runs/pretrain")
    tasks: tuple[str, ...] = ("reach-v3", "push-v3")
    """Meta-World v3 tasks to pretrain on (never one of ML45's held-out five)"""
    camera: str = "corner2"
    image_size: int = 96
    """side of the square camera images the demonstrations store (pixels)"""
    demos_per_task: int = 50
    """successful expert demonstrations per task, from setup seed PRETRAIN_DEMOS.start on"""
    demo_max_failures: int = 50
    """extra setups per task tried in place of the expert's failed rollouts"""
    demo_max_steps: int = 300
    """a demonstration that has not succeeded after this many steps is a failure"""
    collect_workers: int = 2
    train: TrainConfig = field(default_factory=TrainConfig)
    """the training run (its folder, store and gaze settings are the train stage's own)"""
    eval_episodes: int = 10
    """evaluation episodes per task, on setup seeds PRETRAIN_EVAL.start .."""
    eval_max_steps: int = 200
    eval_workers: int = 2
    eval_batch: int | None = None
    """environments a worker steps in lockstep (None: the simulator's default; gazereg.evaluation.config)"""
    progress: bool = True
    """a progress line on stderr for each stage's work: demonstrations collected, training steps (unless
    `--train.no-progress`), evaluation episodes (`gazereg.runtime.progress`)"""

    def validate(self, prefix: str) -> None:
        require_entries(self.tasks, prefix + "tasks", noun="task", show=str)
        for name, low in (("image_size", 8), ("demos_per_task", 1), ("demo_max_failures", 0)):
            require_number(getattr(self, name), prefix + name, low, integer=True)
        for name in ("demo_max_steps", "eval_episodes", "eval_max_steps", "eval_workers"):
            require_number(getattr(self, name), prefix + name, 1, integer=True)
        require_number(self.collect_workers, prefix + "collect_workers", 0, integer=True)
        if self.eval_batch is not None:
            require_number(self.eval_batch, prefix + "eval_batch", 1, integer=True)
        if not self.camera:
            raise UsageError(f"{option(prefix + 'camera')} is empty: name the camera")
        PRETRAIN_DEMOS.require(
            self.demo_seeds,
            f"{option(prefix + 'demos_per_task')} {self.demos_per_task} + "
            f"{option(prefix + 'demo_max_failures')} {self.demo_max_failures}",
        )
        PRETRAIN_EVAL.require(self.eval_seeds, f"{option(prefix + 'eval_episodes')} {self.eval_episodes}")
        if self.train.gaze.prior is not None:
            raise UsageError(
                f"{option(prefix + 'train.gaze.prior')} {self.train.gaze.prior}: pretraining has no gaze term"
            )

    @property
    def demo_seeds(self) -> range:
        """The setup seeds the demonstrations may use (demos plus replacements), per task."""
        return range(
            PRETRAIN_DEMOS.start, PRETRAIN_DEMOS.start + self.demos_per_task + self.demo_max_failures
        )

    @property
    def eval_seeds(self) -> range:
        return range(PRETRAIN_EVAL.start, PRETRAIN_EVAL.start + self.eval_episodes)


EXECUTION_KEYS = (
    "out",
    "collect_workers",
    "eval_workers",
    "eval_batch",
    "progress",
    *(f"train.{k}" for k in TRAIN_EXECUTION_KEYS),
)
"""keys a resumed pretraining may change: how it runs, not what it produces"""


def preflight(cfg: PretrainConfig) -> None:
    """Refuse (UsageError, one line) before any work: a task Meta-World lacks, one of ML45's held-out tasks,
    and a tokenizer (the reference VLA's) that would cut an instruction of the pretraining or the held-out tasks
    or, with words, lacks a word of a held-out instruction (module docstring)."""
    check_tasks("metaworld", cfg.tasks, "--tasks")
    held_out = ml45_split().test
    seen = [t for t in cfg.tasks if t in held_out]
    if seen:
        raise UsageError(f"--tasks: {seen[0]} is one of ML45's held-out tasks ({', '.join(held_out)})")
    if cfg.train.init_from is not None:
        read_init(Path(cfg.train.init_from), cfg.train.policy.type, "--train.init-from")
    kind, length = getattr(cfg.train.policy, "tokenizer", None), getattr(cfg.train.policy, "max_text_len", 0)
    if kind is None:
        return
    known = Tokenizer.build([instruction_for(t) for t in cfg.tasks] + list(cfg.train.data.extra_instructions))
    for task in (*cfg.tasks, *held_out):
        text = instruction_for(task)
        n = len(text.encode("utf-8")) if kind == "bytes" else len(Tokenizer.split(text))
        if n > length:
            raise UsageError(
                f"--train.policy.max-text-len {length} cuts {task}'s instruction ({n} {kind}: {text!r})"
            )
        unknown = list(dict.fromkeys(known.unknown_words(text))) if kind == "words" else []
        if unknown:
            raise UsageError(
                f"--train.data.extra-instructions: the words vocabulary lacks {', '.join(unknown)} of {task}'s "
                f"instruction {text!r}: add the held-out tasks' instructions (or use --train.policy.tokenizer bytes)"
            )


def held_out_instructions() -> tuple[str, ...]:
    """The instructions of ML45's held-out tasks, in the split's order."""
    return tuple(instruction_for(t) for t in ml45_split().test)


def finetune_flags(policy: PolicyConfig, prefix: str = "--train.policy.") -> list[str]:
    """The command-line options that give a run this (unresolved) policy architecture: every field that
    differs from its class's default, e.g. ["--train.policy.dim", "192", "--train.policy.tokenizer", "bytes"]."""
    default = type(policy)()
    out: list[str] = []
    for f in dataclasses.fields(policy):
        value = getattr(policy, f.name)
        if f.name in default.data_fields() or value == getattr(default, f.name):
            continue
        flat = [str(v) for v in (value if isinstance(value, tuple) else (value,))]
        out += [prefix + f.name.replace("_", "-"), *flat]
    return out


# ----- presets ------------------------------------------------------------------------------------------------
def ml45_policy() -> VLAConfig:
    """The generalist's architecture: width 192, 4 layers, 4 heads (about 1.3 M parameters), 96 px images in
    12 px patches (8 x 8 tokens), chunks of 8, 16 word tokens of instruction. Sized by the step time
    benchmarks/bench_pretrain_size.py measures (docs/pretraining.md): the whole pretraining must fit one
    sitting on 2 cores, and every fine-tuning run of the study and `make demo` pays for its size."""
    return VLAConfig(dim=192, depth=4, heads=4, chunk=8, tokenizer="words", max_text_len=TEXT_TOKENS)


def ml45_train() -> TrainConfig:
    """`ml45_policy` trained 30,000 steps of batch 32 with the tuned recipe's learning rate 5e-4, checkpoints
    every 2,000 steps (the newest 3 kept), on the GPU where there is one; the
    tokenizer's vocabulary holds the held-out tasks' words too. Needs Meta-World (the held-out instructions)."""
    t = tuned_train()
    return replace(
        t,
        data=replace(t.data, extra_instructions=held_out_instructions()),
        run_dir=Path("runs/pretrain/train"),
        steps=30_000,
        batch_size=32,
        policy=ml45_policy(),
        save_every=2000,
        keep_checkpoints=3,
        eval_every=1000,
        device="auto",
    )


def ml45() -> PretrainConfig:
    """The real pretraining: Meta-World ML45's 45 training tasks, 50 demonstrations each (300 steps at most, up
    to 50 replacements of the expert's failures), `ml45_train`, then 10 evaluation episodes per task.
    `--train.stop-at N` pauses the training stage with a checkpoint so it can run in sittings of under three
    hours."""
    return PretrainConfig(out=Path("runs/pretrain"), tasks=ml45_split().train, train=ml45_train())


def ml45_continued() -> PretrainConfig:
    """More pretraining of the committed generalist (`GENERALIST`, `ml45`'s policy): the same tasks,
    demonstrations (recollected bit for bit, or resumed from a copy of `ml45`'s store) and evaluation, 30,000
    further steps from its weights with the learning-rate schedule restarted (warmup, then cosine to zero), so
    60,000 steps in all. Added because `ml45` underfits (its validation loss still fell at the end) and its
    fine-tuning did not beat training from scratch (docs/pretraining.md). Its training records the start's
    path and SHA-256 (train/init_from.json)."""
    base = ml45()
    return replace(base, out=Path("runs/pretrain-continued"), train=replace(base.train, init_from=GENERALIST))


def toy() -> PretrainConfig:
    """Every stage at toy size (tests/test_pretrain.py): 2 tasks, 2 demonstrations each at 48 px, a 2-layer
    64-wide policy trained 6 steps, 1 evaluation episode of 10 steps per task."""
    t = ci_train()
    train = replace(
        t,
        steps=6,
        batch_size=8,
        log_every=3,
        eval_every=3,
        save_every=3,
        eval_batch_size=8,
        policy=replace(t.policy, tokenizer="words", max_text_len=TEXT_TOKENS),
        data=replace(t.data, extra_instructions=held_out_instructions()),
        optim=OptimConfig(lr=1e-3, warmup_steps=2),
    )
    return PretrainConfig(
        out=Path("runs/pretrain_toy"),
        tasks=("reach-v3", "button-press-topdown-v3"),
        image_size=48,
        demos_per_task=2,
        demo_max_failures=4,
        demo_max_steps=150,
        collect_workers=1,
        train=train,
        eval_episodes=1,
        eval_max_steps=10,
        eval_workers=1,
    )


PRESETS = {"ml45": ml45, "ml45_continued": ml45_continued, "toy": toy}
"""`gazereg pretrain --preset NAME`"""
DEFAULT_PRESET = "ml45"
"""`gazereg pretrain`'s preset without `--preset`"""
