"""`gazereg train`'s configuration: the data, gaze and optimiser settings, the run, and its presets, the
training recipes (`gazereg presets` lists every kind of preset):

    ci()      CI: a few seconds on a CPU
    cpu()     the tiny VLA on a CPU
    tuned()   `cpu` as tuned without gaze
    gpu()     a GPU-sized run

`gazereg train --preset NAME` starts from PRESETS[NAME]; every field can be overridden on the command line
(e.g. --gaze.prior visuomotor --optim.lr 3e-4). The presets train the reference VLA; `--policy.type NAME`
trains another registered policy (with that policy's default config, then --policy.FIELD overrides).

Every config checks its options when it is built (a `Validated` config: numbers finite and in range, choices
known) and raises UsageError naming the option, e.g. `--gaze.weight must be a finite number >= 0, got nan`.

`--resume` continues the same run: a checkpoint's config must match the one given, except the
EXECUTION_KEYS, which change how the run executes but not the weights it produces. `steps` is not one of
them (the LR and gaze-weight schedules span `steps`): to pause a run, use `stop_at`; to train longer, start a
new run.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, ClassVar, Literal, get_args

from gazereg.attention.probe import QUERY_SETS, QuerySet
from gazereg.losses import Divergence
from gazereg.policies import POLICY_CHOICE, PolicyConfig, policy_class
from gazereg.policies.vla.configuration_vla import VLAConfig
from gazereg.policies.vla.configuration_vla import large as large_policy
from gazereg.runtime.config import Validated, option, require_choice, require_number
from gazereg.runtime.errors import UsageError
from gazereg.training.photometric import PhotometricConfig

EXECUTION_KEYS = (
    "run_dir",
    "resume",
    "stop_at",
    "device",
    "threads",
    "progress",
    "logger",
    "wandb_project",
    "save_every",
    "keep_checkpoints",
    "data.num_workers",
    "data.in_memory",
)
"""dotted TrainConfig keys a resumed run may change: where and how it runs (folder, device, threads, loader
workers, frames in RAM or memory-mapped), what it shows (progress bar, external logger) and which checkpoints
it writes and keeps. Everything else (seed, steps, batch, data, policy, gaze, optimiser, augmentation,
precision, and what metrics.jsonl records: log_every, eval_every, eval_batch_size) must stay the same. Another
device or thread count keeps every setting but rounds differently (CPU reductions split over threads), so a
resume is bit for bit the uninterrupted run only on the same device and thread count."""

WeightKind = Literal["constant", "linear_warmup", "cosine"]
Device = Literal["auto", "cpu", "cuda"]
Precision = Literal["auto", "no", "bf16", "fp16"]
LoggerKind = Literal["none", "tensorboard", "wandb"]
GazeTarget = Literal["attention", "features"]
GAZE_TARGETS: tuple[str, ...] = get_args(GazeTarget)


@dataclass(frozen=True)
class DataConfig(Validated):
    OPTION_PREFIX: ClassVar[str] = "data."

    store: Path = Path("data/demos")
    """episode store (`gazereg collect` / `gazereg import`)"""
    tasks: tuple[str, ...] = ()
    """train on these tasks only (empty: all)"""
    max_episodes: int | None = None
    """at most this many episodes per task"""
    val_fraction: float = 0.1
    """episodes held out per task for the validation loss and attention-gaze alignment (0: use a training batch)"""
    in_memory: bool = True
    """copy frames into RAM (fast); False reads the store's memory maps per sample"""
    num_workers: int = 0
    """DataLoader worker processes (0: batches are built in the training process)"""
    extra_instructions: tuple[str, ...] = ()
    """instructions whose words a "words" tokenizer's vocabulary holds besides the training data's (e.g. held-out
    tasks', so that a policy fine-tuned on them from this one has their words); the bytes tokenizer has every
    text's"""

    def validate(self, prefix: str) -> None:
        if self.max_episodes is not None:
            require_number(self.max_episodes, f"{prefix}max_episodes", 1, integer=True)
        require_number(self.val_fraction, f"{prefix}val_fraction", 0, 1, open_high=True)
        require_number(self.num_workers, f"{prefix}num_workers", 0, integer=True)


@dataclass(frozen=True)
class GazeConfig(Validated):
    OPTION_PREFIX: ClassVar[str] = "gaze."

    prior: str | None = None
    """prior name in the store (`gazereg priors`); unset trains the baseline with no gaze anywhere"""
    enabled: bool = True
    """false: do not regularize (the baseline), but still report attention-gaze alignment at evaluations"""
    camera: str | None = None
    """the camera the prior is for (default: the one recorded in prior.json)"""
    weight: float = 0.1
    schedule: WeightKind = "constant"
    warmup_steps: int = 0
    final_frac: float = 0.0
    layers: tuple[int, ...] = (-2, -1)
    """transformer layers whose attention is regularized (negative: from the end)"""
    divergence: Divergence = "forward"
    """forward = KL(gaze || attention)"""
    patch_eps: float = 1e-6
    """epsilon floor of the gaze patch distributions"""
    loss_eps: float = 1e-8
    target: str = "attention"  # one of GAZE_TARGETS; a str so a bad value gets validate's one-line error
    """what the gaze term supervises (attention or features): attention = KL(gaze || the action queries'
    attention) (the method); features = KL(gaze || a training-only head's distribution over the patches,
    read from the image tokens' features of the last of `layers`), the location control that gives the
    policy the gaze's location information without supervising attention (gazereg.training.location); the
    attention KL is then logged as a diagnostic only"""
    queries: str = "action"  # one of QUERY_SETS (`query_set` is the typed value); a str like `target`
    """whose attention to the patches the gaze term regularizes: action (the action queries), language (the
    instruction's real tokens, padding left out) or both (those rows together, each weighing the same);
    language and both need a policy that gives them (the reference VLA)"""

    def validate(self, prefix: str) -> None:
        require_number(self.weight, f"{prefix}weight", 0)
        require_choice(self.target, f"{prefix}target", GAZE_TARGETS)
        require_choice(self.queries, f"{prefix}queries", QUERY_SETS)
        require_choice(self.schedule, f"{prefix}schedule", get_args(WeightKind))
        require_number(self.warmup_steps, f"{prefix}warmup_steps", 0, integer=True)
        require_number(self.final_frac, f"{prefix}final_frac", 0, 1)
        for layer in self.layers:
            require_number(layer, f"{prefix}layers", integer=True)
        require_choice(self.divergence, f"{prefix}divergence", get_args(Divergence))
        require_number(self.patch_eps, f"{prefix}patch_eps", 0, open_low=True)
        require_number(self.loss_eps, f"{prefix}loss_eps", 0, open_low=True)

    @property
    def query_set(self) -> QuerySet:
        """`queries` as the typed value the policy's `probe_spec` takes."""
        return QuerySet(self.queries)


@dataclass(frozen=True)
class OptimConfig(Validated):
    OPTION_PREFIX: ClassVar[str] = "optim."

    lr: float = 1e-3
    weight_decay: float = 1e-4
    betas: tuple[float, float] = (0.9, 0.999)
    warmup_steps: int = 200
    min_lr_frac: float = 0.0
    """cosine decay from lr to min_lr_frac * lr over the run"""
    grad_clip: float = 1.0
    """max global gradient norm (0: no clipping)"""
    ema_decay: float = 0.0
    """EMA of the weights (saved for evaluation) when > 0, e.g. 0.999"""

    def validate(self, prefix: str) -> None:
        require_number(self.lr, f"{prefix}lr", 0, open_low=True)
        require_number(self.weight_decay, f"{prefix}weight_decay", 0)
        if len(self.betas) != 2:
            raise UsageError(f"{option(prefix + 'betas')} takes two numbers, got {self.betas!r}")
        for beta in self.betas:
            require_number(beta, f"{prefix}betas", 0, 1, open_high=True)
        require_number(self.warmup_steps, f"{prefix}warmup_steps", 0, integer=True)
        require_number(self.min_lr_frac, f"{prefix}min_lr_frac", 0, 1)
        require_number(self.grad_clip, f"{prefix}grad_clip", 0)
        require_number(self.ema_decay, f"{prefix}ema_decay", 0, 1, open_high=True)


@dataclass(frozen=True)
class TrainConfig(Validated):
    run_dir: Path = Path("runs/train")
    seed: int = 0
    steps: int = 1500
    batch_size: int = 64
    """global batch (split across processes)"""
    policy: PolicyConfig = field(default_factory=VLAConfig, metadata=POLICY_CHOICE.metadata())
    """the policy's config: the reference VLA unless `--policy.type NAME` picks another registered policy
    (gazereg.policies), whose fields then take overrides (--policy.FIELD value)"""
    init_from: Path | None = None
    """a saved policy folder (model.safetensors, config.json, tokenizer.json; e.g. `gazereg pretrain`'s
    policy/) whose weights, normalisation statistics and tokenizer the run starts from instead of a fresh
    initialisation; its architecture must be this run's `policy` (gazereg.training.init_from)"""
    data: DataConfig = field(default_factory=DataConfig)
    gaze: GazeConfig = field(default_factory=GazeConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    shift: int = 4
    """random-shift augmentation in input pixels (0: off); gaze targets are not shifted"""
    photometric: PhotometricConfig = field(default_factory=PhotometricConfig)
    """brightness / contrast / saturation jitter of the training frames, every policy (all 0: off;
    gazereg.training.photometric)"""
    log_every: int = 25
    eval_every: int = 250
    """validation loss, attention-gaze alignment and the callbacks (e.g. rollouts) every this many steps"""
    eval_batch_size: int = 64
    save_every: int = 500
    keep_checkpoints: int = 0
    """keep only the newest n checkpoints (0: all)"""
    resume: bool = False
    """continue from the newest checkpoint in run_dir"""
    stop_at: int | None = None
    """stop (with a checkpoint) after this many steps without changing the schedule; resume later"""
    device: Device = "auto"
    mixed_precision: Precision = "auto"
    """autocast dtype of the forward: auto = bf16 where the device multiplies bf16 natively (a CUDA GPU with
    bf16, an AVX-512 BF16 / AMX CPU), else no (float32); the run folder's config.json records the choice.
    The gaze KL, the losses and normalisation stay float32 either way."""
    threads: int | None = None
    """torch intra-op threads per process (default: torch's choice)"""
    progress: bool = True
    logger: LoggerKind = "none"
    wandb_project: str = "gazereg"

    def validate(self, prefix: str) -> None:
        require_number(self.seed, f"{prefix}seed", integer=True)
        for name in ("steps", "batch_size", "log_every", "eval_every", "eval_batch_size", "save_every"):
            require_number(getattr(self, name), prefix + name, 1, integer=True)
        require_number(self.shift, f"{prefix}shift", 0, integer=True)
        require_number(self.keep_checkpoints, f"{prefix}keep_checkpoints", 0, integer=True)
        for name in ("stop_at", "threads"):
            if getattr(self, name) is not None:
                require_number(getattr(self, name), prefix + name, 1, integer=True)
        require_choice(self.device, f"{prefix}device", get_args(Device))
        require_choice(self.mixed_precision, f"{prefix}mixed_precision", get_args(Precision))
        require_choice(self.logger, f"{prefix}logger", get_args(LoggerKind))
        check_layers(self.gaze.layers, self.policy, prefix)
        if self.gaze.query_set is not QuerySet.ACTION:  # one the policy cannot give: refused before any work
            try:
                policy_class(self.policy.type).require_query_set(self.gaze.query_set)
            except UsageError as e:
                raise UsageError(f"{option(prefix + 'gaze.queries')} {self.gaze.queries}: {e}") from e


def check_layers(layers: tuple[int, ...], policy: PolicyConfig, prefix: str = "") -> None:
    """UsageError naming `--gaze.layers` (after `prefix`) when an id is outside the layers of a policy whose
    config states its depth (an integer `depth` field, e.g. the reference VLA's): ids run 0..depth-1, or
    -depth..-1 from the end. Other policies check their ids when built (`Policy.resolve_layers`)."""
    depth = getattr(policy, "depth", None)
    if not isinstance(depth, int) or isinstance(depth, bool) or depth < 1:
        return
    flag = option(prefix + "gaze.layers")
    if not layers:
        raise UsageError(f"{flag} is empty: give at least one layer id in {-depth}..{depth - 1}")
    bad = [layer for layer in layers if not -depth <= layer < depth]
    if bad:
        raise UsageError(
            f"{flag} {' '.join(map(str, bad))} is out of range for a {depth}-layer policy "
            f"({option(prefix + 'policy.depth')} {depth}): layer ids run {-depth}..{depth - 1}"
        )


def upgrade_saved(saved: dict[str, Any]) -> dict[str, Any]:
    """A saved TrainConfig dict (`to_dict` as JSON) with the options added since filled in with the value
    that reproduces how it ran: gaze.target "attention" (runs saved before the option existed regularized
    attention), gaze.queries "action" (they regularized the action queries), data.extra_instructions empty.
    For comparisons with a new config (resume, an experiment folder)."""
    gaze, data = saved.get("gaze"), saved.get("data")
    if isinstance(data, dict) and "extra_instructions" not in data:
        saved = {**saved, "data": {**data, "extra_instructions": []}}
    if isinstance(gaze, dict):
        added = {k: v for k, v in (("target", "attention"), ("queries", "action")) if k not in gaze}
        return {**saved, "gaze": {**gaze, **added}} if added else saved
    return saved


def ci() -> TrainConfig:
    """CI: a few seconds on a CPU (a 2-layer 64-wide policy on 48 px images, 20 steps of batch 8)."""
    return TrainConfig(
        run_dir=Path("runs/smoke"),
        steps=20,
        batch_size=8,
        log_every=5,
        eval_every=10,
        eval_batch_size=16,
        save_every=10,
        policy=VLAConfig(
            image_hw=(48, 48), patch_size=12, dim=64, depth=2, heads=4, stem_channels=16, max_text_len=12
        ),
        optim=OptimConfig(lr=1e-3, warmup_steps=5),
        shift=2,
        device="cpu",
        progress=False,
    )


def cpu() -> TrainConfig:
    """The tiny policy (about 0.6 M parameters, 96 px) on a CPU: 1,500 steps of batch 64."""
    return TrainConfig(run_dir=Path("runs/quick"), device="cpu")


def tuned() -> TrainConfig:
    """`cpu` tuned without gaze on validation setups: learning rate 5e-4, action chunks of 8, 16,000 steps of
    batch 32 (scripts/tune_baseline.py; its choice and every candidate's validation successes in
    docs/tuning/baseline.md). The experiment presets `paper` and `sweep` train with it."""
    q = cpu()
    return replace(
        q,
        steps=16_000,
        batch_size=32,
        policy=replace(q.policy, chunk=8),
        optim=replace(q.optim, lr=5e-4),
    )


def gpu() -> TrainConfig:
    """A GPU-sized run: the `large` policy (224 px, 16 x 16 patches, width 512, 8 layers, chunks of 10), 100,000
    steps of batch 64, EMA, bf16."""
    return TrainConfig(
        run_dir=Path("runs/paper"),
        steps=100_000,
        batch_size=64,
        policy=large_policy(),
        optim=OptimConfig(lr=3e-4, weight_decay=1e-2, warmup_steps=1000, min_lr_frac=0.05, ema_decay=0.999),
        data=DataConfig(num_workers=4, in_memory=False),
        shift=8,
        log_every=100,
        eval_every=5000,
        save_every=5000,
        keep_checkpoints=3,
        mixed_precision="bf16",
        threads=None,
        progress=True,
    )


PRESETS = {"ci": ci, "cpu": cpu, "tuned": tuned, "gpu": gpu}
"""the training recipes, `gazereg train --preset NAME`"""
DEFAULT_PRESET = "ci"
"""`gazereg train`'s recipe without `--preset`"""

smoke, quick, paper = (
    ci,
    cpu,
    gpu,
)  # the recipes' former names, for code that imports them; prefer the new ones
