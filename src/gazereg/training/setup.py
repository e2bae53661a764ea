"""Everything a training run needs before its first step: data, policy, optimiser, resume, Accelerate.

`build` makes the data sets and the policy from a config through the Policy interface only
(`gazereg.policies.base`); `setup` adds the accelerator, the optimiser and LR schedule, the EMA, the restored
checkpoint (with `resume`) and the data loader, and returns them as one `Run`.

`build` refuses (one line, `UsageError`) before any data is read what gazereg.training.guards checks: a batch
larger than the training samples and a gaze prior that does not fit what it would regularize.

At the start `setup` removes the temporaries that killed writers left in the run folder. With `resume` it
reads the newest checkpoint that reads completely (a damaged newer one is skipped with a warning) and refuses
a config that differs from the checkpoint's in anything but the execution keys (training.config); without a
checkpoint the run starts clean (metrics.jsonl of a run killed before its first checkpoint is emptied). Each
attempt that trains a step records this machine's numerics key in numerics.json (training.numerics).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from gazereg.attention.probe import ProbeSpec, QuerySet
from gazereg.data.dataset import (
    EpisodeDataset,
    StepBatchSampler,
    collate_batch,
    describe_store,
    select_episodes,
    split_episodes,
)
from gazereg.data.store import EpisodeStore
from gazereg.losses import WeightSchedule
from gazereg.policies import Policy, make_policy
from gazereg.runtime.config import check_same_config, option, save_config, to_dict
from gazereg.runtime.errors import UsageError
from gazereg.runtime.hardware import native_bf16
from gazereg.runtime.io import sweep_stale_temps
from gazereg.runtime.seeding import seed_everything
from gazereg.training.checkpoint import CheckpointData, latest_checkpoint, read_resumable, restore_checkpoint
from gazereg.training.config import EXECUTION_KEYS, GazeConfig, TrainConfig, upgrade_saved
from gazereg.training.ema import EMA
from gazereg.training.guards import check_batch_size, gaze_camera_for
from gazereg.training.init_from import init_policy, init_record, read_init, write_init_record
from gazereg.training.location import HEAD_NAME, LocationHead, make_location_head
from gazereg.training.logger import MetricsFile, NullLogger, make_logger
from gazereg.training.numerics import record_numerics
from gazereg.training.schedule import lr_lambda, param_groups

log = logging.getLogger(__name__)


@dataclass
class Built:
    """Everything `build` makes from a config (before Accelerate wraps anything)."""

    policy: Policy
    config: TrainConfig
    """the config with the policy config resolved from the data"""
    train_set: EpisodeDataset
    val_set: EpisodeDataset | None
    gaze_camera: str | None
    gaze_grid: tuple[int, int] | None = None
    """(rows, cols) of the patch grid the data set mapped the gaze targets onto (None without a prior)"""
    attention_grid: tuple[int, int] | None = None
    """(rows, cols) of the policy's patch grid for the gaze camera, the probed attention's (None without a
    prior)"""
    init: dict[str, Any] | None = None
    """with --init-from: what the run records of the saved policy it started from (init_from.init_record)"""


def build(cfg: TrainConfig) -> Built:
    """Data sets, the policy (seeded, its config resolved from the data) with normalisation stats, gaze targets."""
    seed_everything(cfg.seed)
    saved = read_init(Path(cfg.init_from), cfg.policy.type) if cfg.init_from is not None else None
    store = EpisodeStore(cfg.data.store)
    episodes = select_episodes(store, cfg.data.tasks, cfg.data.max_episodes)
    train_eps, val_eps = split_episodes(store, episodes, cfg.data.val_fraction, cfg.seed)
    check_batch_size(cfg, store, train_eps, len(val_eps))
    data = describe_store(store, episodes, cfg.policy.cameras)
    if cfg.data.extra_instructions:  # words the tokenizer must know besides the data's (DataConfig)
        data = dataclasses.replace(
            data, instructions=tuple(sorted({*data.instructions, *cfg.data.extra_instructions}))
        )
    if saved is None:
        policy = make_policy(cfg.policy, data)
    else:  # fine-tuning: the saved weights, normalisation and tokenizer (gazereg.training.init_from)
        policy = init_policy(cfg.policy, data, saved, Path(cfg.init_from))
    pcfg = policy.config
    gaze_camera = None
    geometry = None
    if cfg.gaze.prior is not None:
        gaze_camera = gaze_camera_for(cfg, store, episodes, pcfg)
        geometry = policy.geometry(gaze_camera)
        policy.resolve_layers(cfg.gaze.layers)  # fail early on bad layer ids

    def dataset(eps: list[int]) -> EpisodeDataset:
        return EpisodeDataset(
            store,
            eps,
            pcfg.cameras,
            pcfg.chunk,
            policy.tokenizer,
            gaze_prior=cfg.gaze.prior,
            gaze_camera=gaze_camera,
            geometry=geometry,
            gaze_eps=cfg.gaze.patch_eps,
            in_memory=cfg.data.in_memory,
        )

    train_set = dataset(train_eps)
    val_set = dataset(val_eps) if val_eps else None
    if saved is None:
        policy.set_normalization(**train_set.stats())
    built = Built(policy, dataclasses.replace(cfg, policy=pcfg), train_set, val_set, gaze_camera)
    if saved is not None:
        built.init = init_record(Path(cfg.init_from), saved)
    if gaze_camera is not None:
        built.gaze_grid = train_set.gaze_geometry.grid_hw
        built.attention_grid = policy.geometry(gaze_camera).grid_hw
    return built


def fixed_batch(ds: EpisodeDataset, n: int) -> dict[str, Tensor]:
    """n evenly spaced samples (the same at every evaluation)."""
    n = min(n, len(ds))
    idx = torch.linspace(0, len(ds) - 1, n).round().long().tolist()
    return ds.__getitems__(idx)


@dataclass
class Run:
    """A training run ready for its first step (what `setup` returns)."""

    cfg: TrainConfig
    """the resolved config"""
    acc: Any
    """the accelerate.Accelerator"""
    built: Built
    model: nn.Module
    """the policy as Accelerate prepared it (DDP-wrapped with several processes)"""
    opt: torch.optim.Optimizer
    sched: torch.optim.lr_scheduler.LambdaLR
    ema: EMA | None
    sampler: StepBatchSampler
    loader: torch.utils.data.DataLoader
    start: int
    """the first step to run (the resumed checkpoint's step, else 0)"""
    stop: int
    """the step to stop at (cfg.steps, or cfg.stop_at when earlier)"""
    resumed_from: Path | None
    metrics: MetricsFile
    logger: NullLogger
    gaze_spec: ProbeSpec | None
    """the probed attention when the gaze term runs (a prior and gaze.enabled), else None; with
    gaze.queries language / both its query weights are the episodes', so steps use `batch_gaze_spec`"""
    gaze_weight: WeightSchedule
    eval_batches: dict[str, dict[str, Tensor]]
    """fixed batches for `evaluate`: 'val' (or 'train' without validation episodes)"""
    location_head: LocationHead | None = None
    """the location control's training-only head (gaze.target features with the gaze term on), else None"""

    @property
    def policy(self) -> Policy:
        return self.built.policy

    @property
    def main(self) -> bool:
        return bool(self.acc.is_main_process)

    @property
    def run_dir(self) -> Path:
        return Path(self.cfg.run_dir)

    def batch_gaze_spec(self, batch: dict[str, Tensor]) -> ProbeSpec | None:
        """The probed attention for `batch`: `gaze_spec` itself for the action queries (built once), else the
        spec of this batch's instruction tokens (its text_mask (B, L) weighs out the padding)."""
        if self.gaze_spec is None or self.cfg.gaze.query_set is QuerySet.ACTION:
            return self.gaze_spec
        return gaze_spec(self.policy, str(self.built.gaze_camera), self.cfg.gaze, batch["text_mask"])

    def eval_policy(self) -> Policy:
        """The weights evaluations use: the EMA's when enabled, else the policy's."""
        return self.ema.model if self.ema is not None else self.policy

    def autocast(self) -> Any:
        return self.acc.autocast() if self.cfg.mixed_precision != "no" else contextlib.nullcontext()


def trains_on_cuda(cfg: TrainConfig) -> bool:
    """Whether cfg.device means a CUDA GPU: "cuda", or "auto" where one is available."""
    return cfg.device == "cuda" or (cfg.device == "auto" and torch.cuda.is_available())


def resolve_precision(cfg: TrainConfig) -> TrainConfig:
    """cfg with mixed_precision "auto" replaced by what the training device supports: bf16 or no."""
    if cfg.mixed_precision != "auto":
        return cfg
    chosen = "bf16" if native_bf16("cuda" if trains_on_cuda(cfg) else "cpu") else "no"
    return dataclasses.replace(cfg, mixed_precision=chosen)


def make_accelerator(cfg: TrainConfig) -> Any:
    """The accelerate.Accelerator for cfg.device and cfg.mixed_precision (torch threads set first)."""
    from accelerate import Accelerator

    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    acc = Accelerator(cpu=not trains_on_cuda(cfg), mixed_precision=cfg.mixed_precision)
    if cfg.batch_size % acc.num_processes:
        raise UsageError(
            f"{option('batch_size')} {cfg.batch_size} must be divisible by the number of processes "
            f"({acc.num_processes})"
        )
    return acc


def checkpoint_to_resume(cfg: TrainConfig, sweep: bool = True) -> CheckpointData | None:
    """The newest readable checkpoint with --resume (None: start from scratch); refuses to overwrite one
    without, and to resume another policy type. `sweep` (the main process) first removes the temporaries that
    killed writers left in the run folder."""
    run_dir = Path(cfg.run_dir)
    for tmp in sweep_stale_temps(run_dir) if sweep else ():
        log.info("removed %s, left by a killed run", tmp)
    ckpt = read_resumable(run_dir) if cfg.resume else None
    if cfg.resume and ckpt is None:
        log.warning("--resume: no checkpoint in %s, starting from scratch", run_dir)
    if not cfg.resume and latest_checkpoint(run_dir) is not None:
        raise FileExistsError(
            f"{run_dir} already holds checkpoints; pass --resume to continue it or choose another --run-dir"
        )
    if ckpt is not None and ckpt.policy_type != cfg.policy.type:
        raise UsageError(
            f"{ckpt.path} holds a {ckpt.policy_type!r} policy; resume it with --policy.type {ckpt.policy_type}"
        )
    return ckpt


def check_resume_config(ckpt: CheckpointData, cfg: TrainConfig) -> None:
    """Refuse to resume with a resolved config that differs from the checkpoint's in anything but the
    execution keys: the rest of the run would follow other settings than its first part (ConfigMismatch)."""
    saved = ckpt.state.get("config")
    if not isinstance(saved, dict):
        raise UsageError(f"{ckpt.path} records no training config; it cannot be resumed")
    saved = upgrade_saved(saved)
    allowed = ", ".join(option(k) for k in EXECUTION_KEYS)
    check_same_config(
        saved,
        cfg,
        EXECUTION_KEYS,
        ckpt.path,
        f"resuming would continue it with other settings. Resume with the options it was started with (only "
        f"{allowed} may change), or choose another --run-dir",
    )


def make_optimiser(
    policy: Policy, cfg: TrainConfig, head: nn.Module | None = None
) -> tuple[torch.optim.Optimizer, torch.optim.lr_scheduler.LambdaLR, EMA | None]:
    """AdamW over `param_groups` (the fused kernel: one pass over all parameters, about 4x less optimiser time
    than the per-tensor loop on a CPU), the warm-up + cosine LR schedule over cfg.steps, and the EMA. A
    training-only `head` (the location control's) is optimised alike, in groups after the policy's."""
    fused = next(policy.parameters()).device.type in ("cpu", "cuda")
    groups = param_groups(policy, cfg.optim.weight_decay)
    if head is not None:
        groups += [g for g in param_groups(head, cfg.optim.weight_decay) if g["params"]]
    opt = torch.optim.AdamW(groups, lr=cfg.optim.lr, betas=cfg.optim.betas, fused=fused)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda s: lr_lambda(s, cfg.steps, cfg.optim.warmup_steps, cfg.optim.min_lr_frac)
    )
    ema = EMA(policy, cfg.optim.ema_decay) if cfg.optim.ema_decay > 0 else None
    return opt, sched, ema


def restore(
    ckpt: CheckpointData,
    policy: Policy,
    opt: torch.optim.Optimizer,
    sched: torch.optim.lr_scheduler.LambdaLR,
    ema: EMA | None,
    head: nn.Module | None = None,
) -> int:
    """Load weights, optimiser, LR schedule, RNG states (the EMA and the location head) from `ckpt`; returns
    its step."""
    if head is not None:
        if HEAD_NAME not in ckpt.aux:
            raise ValueError(f"{ckpt.path} has no {HEAD_NAME} but gaze.target is features")
        head.load_state_dict(ckpt.aux[HEAD_NAME])
    state = restore_checkpoint(ckpt, policy, opt, sched)
    start = int(state["step"])
    if ema is not None:
        if "ema_state_dict" not in state:
            raise ValueError(f"{ckpt.path} has no EMA weights but optim.ema_decay > 0")
        ema.load_state_dict(state["ema_state_dict"], int(state.get("ema_updates", start)))
    return start


def gaze_parts(cfg: TrainConfig, built: Built) -> tuple[ProbeSpec | None, LocationHead | None]:
    """The probed attention when the gaze term runs (a prior and gaze.enabled) and, with gaze.target
    features, the location head (on the policy's device); (None, None) without the gaze term."""
    g = cfg.gaze
    if g.prior is None or not g.enabled or built.gaze_camera is None:
        return None, None
    masks = None  # language / both: every episode's text mask, so an empty instruction is refused now
    if g.query_set is not QuerySet.ACTION:
        masks = torch.cat([ds.text_mask for ds in (built.train_set, built.val_set) if ds is not None])
    spec = gaze_spec(built.policy, built.gaze_camera, g, masks)
    if g.target != "features":
        return spec, None
    try:
        return spec, make_location_head(built.policy, spec, fixed_batch(built.train_set, 1), cfg.seed)
    except NotImplementedError as e:
        raise UsageError(f"{option('gaze.target')} features: {e}") from e


def gaze_spec(policy: Policy, camera: str, g: GazeConfig, text_mask: Tensor | None = None) -> ProbeSpec:
    """The probed attention of `g.queries` on `g.layers`: the action queries' spec (no batch needed), or for
    language / both the spec of the batch whose text mask (B, L) is `text_mask`; a refusal names the option."""
    try:
        return policy.probe_spec(camera, g.layers, g.query_set, text_mask)
    except UsageError as e:
        raise UsageError(f"{option('gaze.queries')} {g.queries}: {e}") from e


def make_loader(cfg: TrainConfig, built: Built, sampler: StepBatchSampler, acc: Any) -> Any:
    return torch.utils.data.DataLoader(
        built.train_set,
        batch_sampler=sampler,
        num_workers=cfg.data.num_workers,
        collate_fn=collate_batch,
        pin_memory=acc.device.type == "cuda",
        persistent_workers=False,
    )


def setup(cfg: TrainConfig) -> Run:
    """Accelerator, data and policy, optimiser and schedules, the resumed state, the loader: a `Run`."""
    cfg = resolve_precision(cfg)
    acc = make_accelerator(cfg)
    ckpt = checkpoint_to_resume(cfg, sweep=acc.is_main_process)
    built = build(cfg)
    cfg, policy, main = built.config, built.policy, acc.is_main_process
    run_dir = Path(cfg.run_dir)
    policy.to(acc.device)
    gaze_spec, head = gaze_parts(cfg, built)
    opt, sched, ema = make_optimiser(policy, cfg, head)
    metrics = MetricsFile(run_dir / "metrics.jsonl")
    stop = min(cfg.steps, cfg.stop_at) if cfg.stop_at is not None else cfg.steps
    start = 0
    if ckpt is not None:
        check_resume_config(ckpt, cfg)
        start = restore(ckpt, policy, opt, sched, ema, head)
        if main:
            log.info("resumed from %s (step %d)", ckpt.path, start)
    if main:
        metrics.truncate_after(start)  # from scratch (start 0): a clean file, not a killed run's records
        run_dir.mkdir(parents=True, exist_ok=True)
        save_config(cfg, run_dir / "config.json")
        if built.init is not None:
            write_init_record(run_dir, built.init)
        if start < stop:  # the machine that trains these steps (training.numerics)
            record_numerics(run_dir, cfg.mixed_precision, start)
    acc.wait_for_everyone()
    model, opt = acc.prepare(policy, opt)
    rank, world = acc.process_index, acc.num_processes
    sampler = StepBatchSampler(len(built.train_set), cfg.batch_size, cfg.seed, stop, start, rank, world)
    g = cfg.gaze
    logger = make_logger(cfg.logger, run_dir, to_dict(cfg), cfg.wandb_project) if main else NullLogger()
    eval_sets = {"val": built.val_set} if built.val_set is not None else {"train": built.train_set}
    return Run(
        cfg=cfg,
        acc=acc,
        built=built,
        model=model,
        opt=opt,
        sched=sched,
        ema=ema,
        sampler=sampler,
        loader=make_loader(cfg, built, sampler, acc),
        start=start,
        stop=stop,
        resumed_from=ckpt.path if ckpt is not None else None,
        metrics=metrics,
        logger=logger,
        gaze_spec=gaze_spec,
        gaze_weight=WeightSchedule(g.weight, g.schedule, g.warmup_steps, cfg.steps, g.final_frac),
        eval_batches={k: fixed_batch(ds, cfg.eval_batch_size) for k, ds in eval_sets.items()},
        location_head=head,
    )
