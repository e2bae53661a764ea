"""Training GLC on generic clip / gaze tensors (the official recipe, minus the video pipeline).

Data: clips `(N, 3, T, H, W)` (uint8 in [0, 255] or float in [0, 1]), gaze points `(N, T, 2)` normalised
`(u right, v down)` in [0, 1], and `valid (N, T)` (False where the gaze is missing). Targets are Gaussian
heatmaps on the output grid (`gaze_target_maps`), the loss is GLC's KL(prediction || target)
(`glc_kl_loss`), optimised with AdamW (lr 1e-4, wd 0.05 except on 1-D parameters), linear warm-up then
cosine decay to 1e-6, gradient clipping at L2 norm 1.0.

`train_glc` writes `out_dir/checkpoints/step_XXXXXXXX/` folders (model.safetensors, config.json,
optimizer.safetensors, trainer_state.json; each folder appears atomically) and `out_dir/train_log.jsonl`,
and resumes from the newest checkpoint folder. With a map-style dataset the batch order, flips and
drop-path draws of step `s` depend only on `(seed, s)`, so a resumed run repeats an uninterrupted one.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file, save_file
from torch.utils.data import Dataset

from gazereg.gaze.glc.checkpoint import load_glc_checkpoint, save_glc
from gazereg.gaze.glc.model import GLC, frame_softmax, prepare_clip
from gazereg.runtime.io import append_jsonl, atomic_dir

# ---- targets and loss ------------------------------------------------------------------------------
KERNEL_SIZE_AT_64 = 19
SIGMA_AT_64 = 3.2  # OpenCV's default for a 19-tap kernel: 0.3 * ((19 - 1) / 2 - 1) + 0.8


def gaze_target_maps(
    points: torch.Tensor,
    valid: torch.Tensor | None,
    size: tuple[int, int],
    kernel_size: int | None = None,
    sigma: float | None = None,
) -> torch.Tensor:
    """Gaussian target heatmaps, one per gaze point (the official GLC targets, scaled to `size`).

    Args:
        points: `(..., 2)` normalised `(u, v)`; the centre pixel is `(round(v*h), round(u*w))`.
        valid: `(...)` bool; None = all valid.
        size: `(h, w)` of the map (64x64 for the full model).
        kernel_size: odd window size; default 19 at 64 px, scaled (`2*round(9*h/64)+1`).
        sigma: Gaussian sigma in pixels; default `3.2 * h / 64`.

    Returns:
        float32 `(..., h, w)`, each map summing to 1: the Gaussian cut to the window and to the frame,
        renormalised; uniform `1/(h*w)` where the point is invalid, outside [0, 1]^2, or its window
        degenerates at a border.
    """
    h, w = size
    if kernel_size is None:
        kernel_size = 2 * max(1, round((KERNEL_SIZE_AT_64 - 1) / 2 * h / 64)) + 1
    if sigma is None:
        sigma = SIGMA_AT_64 * h / 64
    r = (kernel_size - 1) // 2
    lead = points.shape[:-1]
    pts = points.reshape(-1, 2).float()
    ok = torch.ones(pts.shape[0], dtype=torch.bool) if valid is None else valid.reshape(-1).bool().clone()
    ok &= ((pts >= 0) & (pts <= 1)).all(-1) & torch.isfinite(pts).all(-1)
    pts = torch.where(ok[:, None], pts, torch.zeros_like(pts))
    cx = torch.round(pts[:, 0] * w)  # round half to even, like Python's round
    cy = torch.round(pts[:, 1] * h)
    xs = torch.arange(w, dtype=torch.float32)
    ys = torch.arange(h, dtype=torch.float32)
    dx = xs[None, :] - cx[:, None]  # (F, w)
    dy = ys[None, :] - cy[:, None]  # (F, h)
    gx = torch.exp(-0.5 * (dx / sigma) ** 2) * (dx.abs() <= r)
    gy = torch.exp(-0.5 * (dy / sigma) ** 2) * (dy.abs() <= r)
    # the official code leaves a window of width or height 1 empty (left >= right or top >= bottom)
    ok &= ((dx.abs() <= r).sum(-1) > 1) & ((dy.abs() <= r).sum(-1) > 1)
    maps = gy[:, :, None] * gx[:, None, :]
    maps = maps / maps.sum(dim=(1, 2), keepdim=True).clamp_min(1e-30)
    maps = torch.where(ok[:, None, None], maps, torch.full_like(maps, 1.0 / (h * w)))
    return maps.reshape(*lead, h, w)


def glc_kl_loss(logits: torch.Tensor, target: torch.Tensor, temperature: float = 2.0) -> torch.Tensor:
    """GLC's loss: per frame `KL(p || q) = sum p log(p + 1e-10) - sum p log(q + 1e-10)` with
    `p = softmax(logits / temperature)` over h*w and `q` the target map; summed over frames, divided by
    `T * log(h*w)`, averaged over the batch.

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


# ---- data --------------------------------------------------------------------------------------------
class ClipGazeDataset(Dataset):
    """Map-style dataset over in-memory tensors: item `i` -> `(clip (3,T,H,W), gaze (T,2), valid (T,))`."""

    def __init__(self, clips: torch.Tensor, gaze: torch.Tensor, valid: torch.Tensor | None = None) -> None:
        if clips.ndim != 5 or gaze.shape[:2] != (clips.shape[0], clips.shape[2]) or gaze.shape[-1] != 2:
            raise ValueError(f"clips (N,3,T,H,W) and gaze (N,T,2) expected, got {clips.shape}, {gaze.shape}")
        self.clips, self.gaze = clips, gaze.float()
        self.valid = torch.ones(gaze.shape[:2], dtype=torch.bool) if valid is None else valid.bool()

    def __len__(self) -> int:
        return self.clips.shape[0]

    def __getitem__(self, i: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return self.clips[i], self.gaze[i], self.valid[i]


def moving_dot_clips(
    n: int, frames: int = 8, size: int = 96, seed: int = 0, radius: float = 0.06
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Synthetic egocentric-gaze stand-in: a bright dot drifting over a noisy dark background.

    Returns uint8 clips `(n, 3, frames, size, size)`, gaze `(n, frames, 2)` at the dot centre
    (normalised u, v), and `valid (n, frames)` all True.
    """
    g = torch.Generator().manual_seed(seed)
    start = 0.2 + 0.6 * torch.rand(n, 1, 2, generator=g)
    vel = (torch.rand(n, 1, 2, generator=g) - 0.5) * 0.08
    t = torch.arange(frames, dtype=torch.float32)[None, :, None]
    gaze = (start + vel * t).clamp(0.05, 0.95)
    coords = (torch.arange(size, dtype=torch.float32) + 0.5) / size
    du = coords[None, None, None, :] - gaze[..., 0, None, None]
    dv = coords[None, None, :, None] - gaze[..., 1, None, None]
    dot = torch.exp(-(du**2 + dv**2) / (2 * radius**2))  # (n, T, size, size)
    noise = 0.15 * torch.rand(n, 3, frames, size, size, generator=g)
    colour = 0.6 + 0.4 * torch.rand(n, 3, 1, 1, 1, generator=g)
    clips = (noise + colour * dot[:, None]).clamp(0, 1)
    return (clips * 255).round().to(torch.uint8), gaze, torch.ones(n, frames, dtype=torch.bool)


# ---- schedule, optimizer -----------------------------------------------------------------------------
@dataclass(frozen=True)
class GLCTrainConfig:
    """Optimisation settings (official values by default; `warmup_steps` stands for 5 of 15 epochs)."""

    steps: int = 1000
    batch_size: int = 12
    lr: float = 1e-4
    warmup_start_lr: float = 1e-6
    min_lr: float = 1e-6
    warmup_steps: int = 333
    weight_decay: float = 0.05
    grad_clip: float = 1.0
    temperature: float = 2.0
    random_flip: bool = True
    checkpoint_every: int = 200
    keep_last: int = 2
    log_every: int = 10
    seed: int = 0


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
_STEP_DIR = re.compile(r"^step_(\d{8})$")


def _checkpoint_dirs(out_dir: Path) -> list[tuple[int, Path]]:
    root = out_dir / "checkpoints"
    if not root.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in root.iterdir() if (m := _STEP_DIR.match(p.name)) and p.is_dir()]
    return sorted(found)


def save_training_checkpoint(
    out_dir: Path, step: int, model: GLC, optimizer: torch.optim.Optimizer, extra: dict[str, Any]
) -> Path:
    """Write `out_dir/checkpoints/step_{step:08d}/` atomically (weights, config, optimizer, state)."""
    path = out_dir / "checkpoints" / f"step_{step:08d}"
    sd = optimizer.state_dict()
    tensors = {
        f"state.{idx}.{name}": v.detach().cpu().contiguous()
        for idx, st in sd["state"].items()
        for name, v in st.items()
        if isinstance(v, torch.Tensor)
    }
    scalars = {
        str(idx): {name: v for name, v in st.items() if not isinstance(v, torch.Tensor)}
        for idx, st in sd["state"].items()
    }
    with atomic_dir(path) as tmp:
        save_glc(model, model.cfg, tmp)
        save_file(tensors, str(tmp / "optimizer.safetensors"))
        state = {"step": step, "param_groups": sd["param_groups"], "scalar_state": scalars, **extra}
        (tmp / "trainer_state.json").write_text(json.dumps(state, indent=2, default=_jsonable) + "\n")
    return path


def _jsonable(o: Any) -> Any:
    if isinstance(o, tuple | set):
        return list(o)
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def load_training_checkpoint(path: Path, model: GLC, optimizer: torch.optim.Optimizer) -> dict[str, Any]:
    """Restore weights (strictly) and optimizer state from a checkpoint folder; returns its state JSON."""
    load_glc_checkpoint(model, path / "model.safetensors")
    state = json.loads((path / "trainer_state.json").read_text())
    tensors = load_file(str(path / "optimizer.safetensors"))
    opt_state: dict[int, dict[str, Any]] = {}
    for key, v in tensors.items():
        _, idx, name = key.split(".", 2)
        opt_state.setdefault(int(idx), {})[name] = v
    for idx, st in state.get("scalar_state", {}).items():
        opt_state.setdefault(int(idx), {}).update(st)
    groups = state["param_groups"]
    for g in groups:
        if "betas" in g:
            g["betas"] = tuple(g["betas"])
    optimizer.load_state_dict({"state": opt_state, "param_groups": groups})
    return state


# ---- the loop ----------------------------------------------------------------------------------------
Batch = tuple[torch.Tensor, torch.Tensor, torch.Tensor]


def _as_dataset(data: Any) -> Dataset | None:
    if (
        isinstance(data, tuple | list)
        and len(data) in (2, 3)
        and all(isinstance(x, torch.Tensor) for x in data)
    ):
        return ClipGazeDataset(*data)
    if isinstance(data, dict) and "clips" in data:
        return ClipGazeDataset(data["clips"], data["gaze"], data.get("valid"))
    if hasattr(data, "__getitem__") and hasattr(data, "__len__"):
        return data
    return None


def _unpack(item: Any) -> Batch:
    if isinstance(item, dict):
        clip, gaze, valid = item["clips"], item["gaze"], item.get("valid")
    else:
        clip, gaze, *rest = item
        valid = rest[0] if rest else None
    if valid is None:
        valid = torch.ones(gaze.shape[:-1], dtype=torch.bool)
    return clip, gaze, valid


def _dataset_batches(ds: Dataset, batch_size: int, seed: int, start_step: int) -> Iterator[Batch]:
    """Batch of step s = positions [s*B, (s+1)*B) of the endless concatenation of per-epoch permutations
    (epoch e uses a generator seeded by (seed, e)), so any step's batch is reproducible."""
    n = len(ds)
    pos = start_step * batch_size
    perm_epoch, perm = -1, None
    while True:
        idx = []
        for p in range(pos, pos + batch_size):
            e = p // n
            if e != perm_epoch:
                perm = torch.randperm(n, generator=torch.Generator().manual_seed(seed * 1_000_003 + e))
                perm_epoch = e
            idx.append(int(perm[p % n]))
        items = [_unpack(ds[i]) for i in idx]
        yield tuple(torch.stack([it[k] for it in items]) for k in range(3))  # type: ignore[misc]
        pos += batch_size


def _iter_batches(data: Iterable) -> Iterator[Batch]:
    for item in data:
        yield _unpack(item)


def train_glc(
    model: GLC,
    data: Any,
    cfg: GLCTrainConfig,
    out_dir: str | Path,
    *,
    resume: bool = True,
    callback: Callable[[int, float], None] | None = None,
) -> dict[str, Any]:
    """Train `model` for `cfg.steps` optimizer steps (counting those of a resumed run).

    Args:
        model: a `GLC`; it stays on its current device.
        data: `(clips, gaze[, valid])` tensors, a dict with those keys, a map-style dataset of such
            items, or an iterable of batches `(clips (B,3,T,H,W), gaze (B,T,2)[, valid (B,T)])`.
            Clips are converted with `prepare_clip` (uint8 or [0,1] floats, resized to the crop size).
        cfg: optimisation settings.
        out_dir: where checkpoints and `train_log.jsonl` go.
        resume: continue from the newest checkpoint in `out_dir` if there is one.
        callback: called as `callback(step, loss)` after every step.

    Returns:
        `{"step": final step, "losses": [(step, loss), ...] of this call, "checkpoint": last folder}`.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    device = next(model.parameters()).device
    optimizer = make_optimizer(model, cfg)
    step = 0
    last_ckpt: Path | None = None
    if resume and (ckpts := _checkpoint_dirs(out_dir)):
        step, last_ckpt = ckpts[-1]
        load_training_checkpoint(last_ckpt, model, optimizer)
    ds = _as_dataset(data)
    if ds is not None:
        batches = _dataset_batches(ds, cfg.batch_size, cfg.seed, step)
    else:
        batches = _iter_batches(data)
    out_hw = model.cfg.output_shape[1:]
    losses: list[tuple[int, float]] = []
    model.train()
    t0 = time.perf_counter()
    while step < cfg.steps:
        try:
            clips, gaze, valid = next(batches)
        except StopIteration:
            break
        torch.manual_seed(cfg.seed * 1_000_003 + step + 1)  # drop-path and flips: a function of (seed, step)
        x = prepare_clip(clips, model.cfg).to(device)
        gaze = gaze.float().clone()
        if cfg.random_flip:
            flip = torch.rand(x.shape[0]) < 0.5
            x[flip] = x[flip].flip(-1)
            gaze[flip, :, 0] = 1.0 - gaze[flip, :, 0]
        target = gaze_target_maps(gaze, valid, out_hw).to(device)
        for g in optimizer.param_groups:
            g["lr"] = lr_at(step, cfg)
        loss = glc_kl_loss(model(x), target, cfg.temperature)
        if not torch.isfinite(loss):
            raise FloatingPointError(f"non-finite loss at step {step}")
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        grad_norm = torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
        optimizer.step()
        step += 1
        loss_v = float(loss.detach())
        losses.append((step, loss_v))
        if callback is not None:
            callback(step, loss_v)
        if step % cfg.log_every == 0 or step == cfg.steps:
            append_jsonl(
                out_dir / "train_log.jsonl",
                {
                    "step": step,
                    "loss": loss_v,
                    "lr": optimizer.param_groups[0]["lr"],
                    "grad_norm": float(grad_norm),
                    "seconds": round(time.perf_counter() - t0, 3),
                },
            )
        if step % cfg.checkpoint_every == 0 or step == cfg.steps:
            last_ckpt = save_training_checkpoint(
                out_dir, step, model, optimizer, {"train_config": asdict(cfg)}
            )
            for _, old in _checkpoint_dirs(out_dir)[: -max(cfg.keep_last, 1)]:
                shutil.rmtree(old, ignore_errors=True)
    model.eval()
    return {"step": step, "losses": losses, "checkpoint": str(last_ckpt) if last_ckpt else None}


@torch.no_grad()
def evaluate_loss(model: GLC, data: Any, batch_size: int = 8, temperature: float = 2.0) -> float:
    """Mean `glc_kl_loss` of `model` (eval mode) over a dataset / `(clips, gaze[, valid])` tensors."""
    ds = _as_dataset(data)
    if ds is None:
        raise TypeError("evaluate_loss needs a map-style dataset or tensors")
    was_training = model.training
    model.eval()
    device = next(model.parameters()).device
    total, count = 0.0, 0
    for i in range(0, len(ds), batch_size):
        items = [_unpack(ds[j]) for j in range(i, min(i + batch_size, len(ds)))]
        clips, gaze, valid = (torch.stack([it[k] for it in items]) for k in range(3))
        target = gaze_target_maps(gaze.float(), valid, model.cfg.output_shape[1:]).to(device)
        loss = glc_kl_loss(model(prepare_clip(clips, model.cfg).to(device)), target, temperature)
        total += float(loss) * len(items)
        count += len(items)
    model.train(was_training)
    return total / count
