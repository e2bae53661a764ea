"""Training GLC on clip / gaze tensors (the official recipe, minus the video pipeline).

Data: see `gazereg.training.glc_data` (clips `(N, 3, T, H, W)`, gaze `(N, T, 2)`, valid `(N, T)`). Targets
are Gaussian heatmaps on the output grid (`gazereg.gaze.glc.targets.gaze_target_maps`), the loss is GLC's
KL(prediction || target) (`glc_kl_loss`), optimised with AdamW (lr 1e-4, wd 0.05 except on 1-D parameters),
linear warm-up from 1e-6 then cosine decay to 1e-6 (`lr_at`), gradient clipping at L2 norm 1.0.

What it shares with the policy trainer: the batch order (`gazereg.data.dataset.StepBatchSampler`, through
`gazereg.training.glc_data`) and the checkpoint layout and files (`gazereg.training.checkpoint`):

    out_dir/checkpoints/step_000200/
      model.safetensors, config.json      the GLC (`gazereg.gaze.glc.checkpoint.load_glc` reads it)
      training_state/
        state.json                        step and the resolved GLCTrainConfig
        optimizer.safetensors + .json     optimizer tensors + param groups and scalars
    out_dir/train_log.jsonl               step, loss, lr, grad_norm, seconds (every `log_every` steps)

What it keeps of its own, to stay the official recipe: the learning rate (`lr_at` starts the warm-up at
`warmup_start_lr` and reaches `lr` at step `warmup_steps`, and interpolates absolute rates, where
`gazereg.training.schedule.lr_lambda` is a multiplier that reaches 1 one step earlier), the parameter groups
(only 1-D parameters go without weight decay; `schedule.param_groups` also exempts embeddings and position
tables), and the random draws: drop-path and flips use torch's global generator, seeded from `(seed, step)`
before every step, so a resumed run (no RNG state needed in the checkpoint) repeats an uninterrupted one.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import torch

from gazereg.gaze.glc.checkpoint import WEIGHTS_NAME, load_glc_checkpoint, save_glc
from gazereg.gaze.glc.model import GLC, frame_softmax, prepare_clip
from gazereg.gaze.glc.targets import gaze_target_maps
from gazereg.runtime.config import Validated, require_number
from gazereg.runtime.io import append_jsonl, atomic_dir
from gazereg.training.checkpoint import (
    STATE_DIR,
    checkpoint_dir,
    latest_checkpoint,
    load_tensors_json,
    prune_checkpoints,
    save_tensors_json,
)
from gazereg.training.glc_data import Batch, as_clip_dataset, stack_items, training_batches


def glc_kl_loss(logits: torch.Tensor, target: torch.Tensor, temperature: float = 2.0) -> torch.Tensor:
    """GLC's loss: per frame `KL(p || q) = sum p log(p + 1e-10) - sum p log(q + 1e-10)` with
    `p = softmax(logits / temperature)` over h*w and `q` the target map; summed over frames, divided by
    `T * log(h*w)`, averaged over the batch. Returns a scalar.

    Args:
        logits: `(B, 1, T, h, w)` or `(B, T, h, w)`.
        target: `(B, T, h, w)` maps summing to 1 per frame.
    """
    p = frame_softmax(logits, temperature)
    b, t, h, w = p.shape
    p = p.reshape(b, t, h * w)
    q = target.reshape(b, t, h * w).to(p.dtype)
    kl = (p * torch.log(p + 1e-10)).sum(-1) - (p * torch.log(q + 1e-10)).sum(-1)
    return (kl.sum(-1) / (t * math.log(h * w))).mean()


@dataclass(frozen=True)
class GLCTrainConfig(Validated):
    """Optimisation settings (official values by default; `warmup_steps` stands for 5 of 15 epochs), checked
    when built (`validate`; the `gazereg glc train` options are `--optim.*`)."""

    OPTION_PREFIX: ClassVar[str] = "optim."

    steps: int = 1000
    batch_size: int = 12
    lr: float = 1e-4
    warmup_start_lr: float = 1e-6
    min_lr: float = 1e-6
    warmup_steps: int = 333
    weight_decay: float = 0.05
    grad_clip: float = 1.0
    """maximum L2 norm of all gradients together"""
    temperature: float = 2.0
    random_flip: bool = True
    """flip half of each batch left-right (clips and gaze u)"""
    checkpoint_every: int = 200
    keep_last: int = 2
    """checkpoints kept on disk (at least 1)"""
    log_every: int = 10
    seed: int = 0

    def validate(self, prefix: str) -> None:
        """UsageError naming the first option out of range."""
        for name in ("steps", "batch_size", "checkpoint_every", "keep_last", "log_every"):
            require_number(getattr(self, name), prefix + name, 1, integer=True)
        require_number(self.warmup_steps, prefix + "warmup_steps", 0, integer=True)
        require_number(self.seed, prefix + "seed", integer=True)
        for name in ("lr", "grad_clip", "temperature"):
            require_number(getattr(self, name), prefix + name, 0, open_low=True)
        for name in ("warmup_start_lr", "min_lr", "weight_decay"):
            require_number(getattr(self, name), prefix + name, 0)


def lr_at(step: int, cfg: GLCTrainConfig) -> float:
    """Linear warm-up from `warmup_start_lr` to `lr`, then cosine from `lr` to `min_lr` at `cfg.steps`."""
    if step < cfg.warmup_steps:
        return cfg.warmup_start_lr + (cfg.lr - cfg.warmup_start_lr) * step / cfg.warmup_steps
    span = max(cfg.steps - cfg.warmup_steps, 1)
    frac = min((step - cfg.warmup_steps) / span, 1.0)
    return cfg.min_lr + (cfg.lr - cfg.min_lr) * 0.5 * (1.0 + math.cos(math.pi * frac))


def make_optimizer(model: torch.nn.Module, cfg: GLCTrainConfig) -> torch.optim.AdamW:
    """AdamW with weight decay on every parameter of 2+ dims, none on 1-D ones (norms, biases)."""
    decay, no_decay = [], []
    for _, p in model.named_parameters():
        if p.requires_grad:
            (no_decay if p.ndim <= 1 else decay).append(p)
    groups = [
        {"params": decay, "weight_decay": cfg.weight_decay},
        {"params": no_decay, "weight_decay": 0.0},
    ]
    return torch.optim.AdamW(groups, lr=cfg.lr, betas=(0.9, 0.999))


# ---- checkpoints -------------------------------------------------------------------------------------
def save_training_checkpoint(
    out_dir: Path, step: int, model: GLC, optimizer: torch.optim.Optimizer, cfg: GLCTrainConfig
) -> Path:
    """Write `out_dir/checkpoints/step_{step:06d}/` atomically (layout in the module docstring)."""
    path = checkpoint_dir(out_dir, step)
    with atomic_dir(path) as tmp:
        save_glc(model, model.cfg, tmp)
        state_dir = tmp / STATE_DIR
        state_dir.mkdir()
        save_tensors_json(state_dir, "optimizer", optimizer.state_dict())
        state = {"step": step, "train_config": asdict(cfg)}
        (state_dir / "state.json").write_text(json.dumps(state, indent=2, sort_keys=True) + "\n")
    return path


def load_training_checkpoint(path: Path, model: GLC, optimizer: torch.optim.Optimizer) -> dict[str, Any]:
    """Restore weights (strictly) and optimizer state from a checkpoint folder; returns its state.json."""
    load_glc_checkpoint(model, path / WEIGHTS_NAME)
    optimizer.load_state_dict(load_tensors_json(path / STATE_DIR, "optimizer"))
    return json.loads((path / STATE_DIR / "state.json").read_text())


# ---- the loop ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GLCTrainResult:
    """What one `train_glc` call did."""

    step: int
    """the step reached (counting the steps of a resumed run)"""
    losses: list[tuple[int, float]] = field(default_factory=list)
    """`(step, loss)` of every step this call ran"""
    checkpoint: Path | None = None
    """the newest checkpoint folder, if any"""


def _train_step(
    model: GLC, optimizer: torch.optim.Optimizer, batch: Batch, step: int, cfg: GLCTrainConfig
) -> tuple[float, float]:
    """One optimizer step on `batch` at schedule step `step`; returns `(loss, gradient norm)`."""
    clips, gaze, valid = batch
    device = next(model.parameters()).device
    torch.manual_seed(cfg.seed * 1_000_003 + step + 1)  # drop-path and flips: a function of (seed, step)
    x = prepare_clip(clips, model.cfg).to(device)
    gaze = gaze.float().clone()
    if cfg.random_flip:
        flip = torch.rand(x.shape[0]) < 0.5
        x[flip] = x[flip].flip(-1)
        gaze[flip, :, 0] = 1.0 - gaze[flip, :, 0]
    target = gaze_target_maps(gaze, valid, model.cfg.output_shape[1:]).to(device)
    for g in optimizer.param_groups:
        g["lr"] = lr_at(step, cfg)
    loss = glc_kl_loss(model(x), target, cfg.temperature)
    if not torch.isfinite(loss):
        raise FloatingPointError(f"non-finite loss at step {step}")
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    grad_norm = torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
    optimizer.step()
    return float(loss.detach()), float(grad_norm)


def train_glc(
    model: GLC,
    data: Any,
    cfg: GLCTrainConfig,
    out_dir: str | Path,
    *,
    resume: bool = True,
    callback: Callable[[int, float], None] | None = None,
) -> GLCTrainResult:
    """Train `model` for `cfg.steps` optimizer steps (counting those of a resumed run).

    Args:
        model: a `GLC`; it stays on its current device (and is left in eval mode).
        data: `(clips, gaze[, valid])` tensors, a dict with those keys, a map-style dataset of such
            items, or an iterable of batches `(clips (B,3,T,H,W), gaze (B,T,2)[, valid (B,T)])`.
            Clips are converted with `prepare_clip` (uint8 or [0,1] floats, resized to the crop size).
        cfg: optimisation settings.
        out_dir: where checkpoints and `train_log.jsonl` go.
        resume: continue from the newest checkpoint in `out_dir` if there is one.
        callback: called as `callback(step, loss)` after every step.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    optimizer = make_optimizer(model, cfg)
    step, last = 0, latest_checkpoint(out_dir) if resume else None
    if last is not None:
        step = int(load_training_checkpoint(last, model, optimizer)["step"])
    batches = training_batches(data, cfg.batch_size, cfg.seed, step, cfg.steps)
    losses: list[tuple[int, float]] = []
    model.train()
    t0 = time.perf_counter()
    while step < cfg.steps and (batch := next(batches, None)) is not None:
        loss, grad_norm = _train_step(model, optimizer, batch, step, cfg)
        step += 1
        losses.append((step, loss))
        if callback is not None:
            callback(step, loss)
        if step % cfg.log_every == 0 or step == cfg.steps:
            lr = optimizer.param_groups[0]["lr"]
            seconds = round(time.perf_counter() - t0, 3)
            record = {"step": step, "loss": loss, "lr": lr, "grad_norm": grad_norm, "seconds": seconds}
            append_jsonl(out_dir / "train_log.jsonl", record)
        if step % cfg.checkpoint_every == 0 or step == cfg.steps:
            last = save_training_checkpoint(out_dir, step, model, optimizer, cfg)
            prune_checkpoints(out_dir, max(cfg.keep_last, 1))
    model.eval()
    return GLCTrainResult(step, losses, last)


@torch.no_grad()
def evaluate_loss(model: GLC, data: Any, batch_size: int = 8, temperature: float = 2.0) -> float:
    """Mean `glc_kl_loss` of `model` (eval mode) over a dataset / `(clips, gaze[, valid])` tensors."""
    ds = as_clip_dataset(data)
    if ds is None:
        raise TypeError("evaluate_loss needs a map-style dataset or tensors")
    was_training = model.training
    model.eval()
    device = next(model.parameters()).device
    total, count = 0.0, 0
    for i in range(0, len(ds), batch_size):
        indices = range(i, min(i + batch_size, len(ds)))
        clips, gaze, valid = stack_items(ds, indices)
        target = gaze_target_maps(gaze.float(), valid, model.cfg.output_shape[1:]).to(device)
        loss = glc_kl_loss(model(prepare_clip(clips, model.cfg).to(device)), target, temperature)
        total += float(loss) * len(indices)
        count += len(indices)
    model.train(was_training)
    return total / count
