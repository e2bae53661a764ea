"""`gazereg train`'s configuration: the data, gaze and optimiser settings, the run, and the presets.

    smoke()   CI: a few seconds on a CPU
    quick()   the README's CPU job
    paper()   a GPU-sized run

`gazereg train --preset NAME` starts from PRESETS[NAME]; every field can be overridden on the command line
(e.g. --gaze.prior visuomotor --optim.lr 3e-4). The presets train the reference VLA; `--policy.type NAME`
trains another registered policy (with that policy's default config, then --policy.FIELD overrides).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from gazereg.losses import Divergence
from gazereg.policies import POLICY_CHOICE, PolicyConfig
from gazereg.policies.vla.configuration_vla import VLAConfig
from gazereg.policies.vla.configuration_vla import paper as paper_policy


@dataclass(frozen=True)
class DataConfig:
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


@dataclass(frozen=True)
class GazeConfig:
    prior: str | None = None
    """prior name in the store (`gazereg priors`); unset trains the baseline with no gaze anywhere"""
    enabled: bool = True
    """false: do not regularize (the baseline), but still report attention-gaze alignment at evaluations"""
    camera: str | None = None
    """the camera the prior is for (default: the one recorded in prior.json)"""
    weight: float = 0.1
    schedule: Literal["constant", "linear_warmup", "cosine"] = "constant"
    warmup_steps: int = 0
    final_frac: float = 0.0
    layers: tuple[int, ...] = (-2, -1)
    """transformer layers whose attention is regularized (negative: from the end)"""
    divergence: Divergence = "forward"
    """forward = KL(gaze || attention)"""
    patch_eps: float = 1e-6
    """epsilon floor of the gaze patch distributions"""
    loss_eps: float = 1e-8


@dataclass(frozen=True)
class OptimConfig:
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


@dataclass(frozen=True)
class TrainConfig:
    run_dir: Path = Path("runs/train")
    seed: int = 0
    steps: int = 1500
    batch_size: int = 64
    """global batch (split across processes)"""
    policy: PolicyConfig = field(default_factory=VLAConfig, metadata=POLICY_CHOICE.metadata())
    """the policy's config: the reference VLA unless `--policy.type NAME` picks another registered policy
    (gazereg.policies), whose fields then take overrides (--policy.FIELD value)"""
    data: DataConfig = field(default_factory=DataConfig)
    gaze: GazeConfig = field(default_factory=GazeConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    shift: int = 4
    """random-shift augmentation in input pixels (0: off); gaze targets are not shifted"""
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
    device: Literal["auto", "cpu", "cuda"] = "auto"
    mixed_precision: Literal["no", "bf16", "fp16"] = "no"
    threads: int | None = None
    """torch intra-op threads per process (default: torch's choice)"""
    progress: bool = True
    logger: Literal["none", "tensorboard", "wandb"] = "none"
    wandb_project: str = "gazereg"


def smoke() -> TrainConfig:
    """CI: a few seconds on a CPU (a 2-layer 64-wide policy on 48 px images)."""
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


def quick() -> TrainConfig:
    """The README's CPU job: the tiny policy (about 0.6 M parameters, 96 px), 1,500 steps of batch 64."""
    return TrainConfig(run_dir=Path("runs/quick"), device="cpu")


def paper() -> TrainConfig:
    """A GPU-sized run: 224 px, 16 x 16 patches, width 512, 8 layers, chunks of 10, EMA, bf16."""
    return TrainConfig(
        run_dir=Path("runs/paper"),
        steps=100_000,
        batch_size=64,
        policy=paper_policy(),
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


PRESETS = {"smoke": smoke, "quick": quick, "paper": paper}
