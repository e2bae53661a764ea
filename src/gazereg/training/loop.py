"""`gazereg train`: one training loop for baseline and gaze-regularized policies.

    gazereg train --preset quick --data.store data/demos --run-dir runs/base
    gazereg train --preset quick --data.store data/demos --run-dir runs/gaze --gaze.prior visuomotor
    gazereg train ... --resume                                   (continue from the newest checkpoint)
    accelerate launch --multi_gpu --num_processes 2 -m gazereg.training.loop --preset smoke ...   (DDP; CPU: gloo)

Loss per step:  L = L_action + w(step) * mean_{valid b} KL(gaze_b || attention_b)
where attention_b is the action queries' attention to the gaze camera's patch tokens on `gaze.layers`
(captured by an AttentionProbe, averaged over heads, queries and layers, renormalised over the patches) and
gaze_b the stored prior mapped onto the policy's patch grid once when the data set is built.

Baseline and gaze runs share everything else: `gaze.prior` unset (or `gaze.enabled=false`) trains without the
probe; `gaze.weight=0` runs the probe and logs the KL without adding it; both reproduce the same parameters
bit for bit on the CPU with the same seed (the probe reads q and k, consumes no RNG and leaves the fused
attention untouched). Every random draw comes from generators seeded by (seed, step, rank) and the batch
order is a function of (seed, step), so `--resume` continues the exact trajectory of an uninterrupted run.

The run folder: config.json (resolved), metrics.jsonl (loss/action, loss/gaze_kl, gaze/weight, lr, timings;
val/* and align/* at every eval), checkpoints/step_XXXXXX/ (see gazereg.training.checkpoint).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from gazereg.attention.probe import AttentionProbe
from gazereg.data.dataset import (
    EpisodeDataset,
    StepBatchSampler,
    collate_batch,
    describe_store,
    select_episodes,
    split_episodes,
)
from gazereg.data.store import EpisodeStore
from gazereg.losses import WeightSchedule, gaze_loss
from gazereg.metrics import alignment_metrics
from gazereg.policies import make_policy
from gazereg.policies.vla.processor_vla import Tokenizer
from gazereg.runtime.config import save_config, to_dict
from gazereg.runtime.seeding import seed_everything
from gazereg.training.checkpoint import latest_checkpoint, load_checkpoint, prune_checkpoints, save_checkpoint
from gazereg.training.config import (  # re-exported: gazereg.training.loop is where callers import them from
    PRESETS,
    TrainConfig,
)
from gazereg.training.ema import EMA
from gazereg.training.logger import MetricsFile, make_logger
from gazereg.training.schedule import lr_lambda, param_groups, step_generator

log = logging.getLogger(__name__)

Callback = Callable[[int, nn.Module], "dict[str, Any] | None"]


@dataclass
class Built:
    """Everything `build` makes from a config (before Accelerate wraps anything)."""

    policy: nn.Module
    config: TrainConfig
    train_set: EpisodeDataset
    val_set: EpisodeDataset | None
    gaze_camera: str | None


def build(cfg: TrainConfig) -> Built:
    """Data set, tokenizer, resolved policy config, policy (seeded) with normalisation stats, gaze targets."""
    seed_everything(cfg.seed)
    store = EpisodeStore(cfg.data.store)
    episodes = select_episodes(store, cfg.data.tasks, cfg.data.max_episodes)
    train_eps, val_eps = split_episodes(store, episodes, cfg.data.val_fraction, cfg.seed)
    info = describe_store(store, episodes, cfg.policy.cameras)
    tok = Tokenizer.build(info.instructions, cfg.policy.tokenizer, cfg.policy.max_text_len)
    pcfg = cfg.policy.resolve(
        cameras=info.cameras,
        camera_hw=info.camera_hw,
        state_dim=info.state_dim,
        action_dim=info.action_dim,
        vocab_size=tok.vocab_size,
    )
    policy = make_policy(cfg.policy_type, pcfg, tokenizer=tok)
    gaze_camera = None
    geometry = None
    if cfg.gaze.prior is not None:
        gaze_camera = cfg.gaze.camera or store.prior_info(cfg.gaze.prior).get("camera")
        if gaze_camera is None:
            raise ValueError(f"prior {cfg.gaze.prior!r} records no camera; set --gaze.camera")
        geometry = policy.geometry(gaze_camera)
        policy.resolve_layers(cfg.gaze.layers)  # fail early on bad layer ids

    def dataset(eps: list[int]) -> EpisodeDataset:
        return EpisodeDataset(
            store,
            eps,
            pcfg.cameras,
            pcfg.chunk,
            tok,
            gaze_prior=cfg.gaze.prior,
            gaze_camera=gaze_camera,
            geometry=geometry,
            gaze_eps=cfg.gaze.patch_eps,
            in_memory=cfg.data.in_memory,
        )

    train_set = dataset(train_eps)
    val_set = dataset(val_eps) if val_eps else None
    policy.normalizer.set_stats(**train_set.stats())
    return Built(policy, dataclasses.replace(cfg, policy=pcfg), train_set, val_set, gaze_camera)


def fixed_batch(ds: EpisodeDataset, n: int) -> dict[str, Tensor]:
    """n evenly spaced samples (the same at every evaluation)."""
    n = min(n, len(ds))
    idx = torch.linspace(0, len(ds) - 1, n).round().long().tolist()
    return ds.__getitems__(idx)


@torch.no_grad()
def evaluate_batch(
    policy: nn.Module, batch: dict[str, Tensor], cfg: TrainConfig, gaze_camera: str | None, prefix: str
) -> dict[str, float]:
    """Action loss and, with a prior, the attention-gaze alignment on one fixed batch (no RNG consumed)."""
    was_training = policy.training
    policy.eval()
    gen = step_generator(cfg.seed, -1, 0, policy.device)
    out: dict[str, float] = {}
    try:
        probe_ctx: Any = contextlib.nullcontext()
        if gaze_camera is not None and "gaze" in batch:
            probe_ctx = AttentionProbe(
                policy, policy.gaze_probe_spec(gaze_camera, cfg.gaze.layers), adapter="tap"
            )
        with probe_ctx as probe:
            loss, _ = policy(batch, generator=gen)
        out[f"{prefix}/loss_action"] = float(loss)
        if probe is not None:
            dev = policy.device
            attn = probe.distribution()
            gaze, valid = batch["gaze"].to(dev), batch["gaze_valid"].to(dev)
            kl, _ = gaze_loss(gaze, attn, valid, cfg.gaze.divergence, cfg.gaze.loss_eps)
            out[f"{prefix}/gaze_kl"] = float(kl)
            out[f"{prefix}/patch_mass"] = float(probe.patch_mass().mean())
            out.update(
                {
                    f"align_{prefix}/{k}": v
                    for k, v in alignment_metrics(gaze.cpu(), attn.cpu(), valid.cpu()).items()
                }
            )
    finally:
        policy.train(was_training)
    return out


# ----- the loop -------------------------------------------------------------------------------------------
def train(cfg: TrainConfig, callbacks: Sequence[Callback] = ()) -> dict[str, Any]:
    """Train; returns {'run_dir', 'step', 'checkpoint', 'metrics' (the last record)}.

    callbacks: called every `eval_every` steps and at the end on the main process as cb(step, policy) with the
    evaluation policy (EMA weights if enabled) in eval mode; a returned dict is merged into the metrics."""
    from accelerate import Accelerator
    from tqdm import tqdm

    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    use_cpu = cfg.device == "cpu" or (cfg.device == "auto" and not torch.cuda.is_available())
    acc = Accelerator(cpu=use_cpu, mixed_precision=cfg.mixed_precision)
    rank, world, main = acc.process_index, acc.num_processes, acc.is_main_process
    if cfg.batch_size % world:
        raise ValueError(
            f"batch_size {cfg.batch_size} must be divisible by the number of processes ({world})"
        )
    run_dir = Path(cfg.run_dir)
    ckpt = latest_checkpoint(run_dir) if cfg.resume else None
    if cfg.resume and ckpt is None:
        log.warning("--resume: no checkpoint in %s, starting from scratch", run_dir)
    if not cfg.resume and latest_checkpoint(run_dir) is not None:
        raise FileExistsError(
            f"{run_dir} already holds checkpoints; pass --resume to continue it or choose another --run-dir"
        )

    built = build(cfg)
    cfg, policy = built.config, built.policy
    policy.to(acc.device)
    total = cfg.steps
    stop = min(total, cfg.stop_at) if cfg.stop_at is not None else total
    opt = torch.optim.AdamW(
        param_groups(policy, cfg.optim.weight_decay), lr=cfg.optim.lr, betas=cfg.optim.betas
    )
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda s: lr_lambda(s, total, cfg.optim.warmup_steps, cfg.optim.min_lr_frac)
    )
    ema = EMA(policy, cfg.optim.ema_decay) if cfg.optim.ema_decay > 0 else None
    start = 0
    metrics = MetricsFile(run_dir / "metrics.jsonl")
    if ckpt is not None:
        state = load_checkpoint(ckpt, policy, opt, sched)
        start = int(state["step"])
        if ema is not None:
            if "ema_state_dict" not in state:
                raise ValueError(f"{ckpt} has no EMA weights but optim.ema_decay > 0")
            ema.load_state_dict(state["ema_state_dict"], int(state.get("ema_updates", start)))
        if state.get("steps") != total:
            log.warning(
                "resuming a run planned for %s steps with steps=%d: the LR schedule changes",
                state.get("steps"),
                total,
            )
        if main:
            metrics.truncate_after(start)
            log.info("resumed from %s (step %d)", ckpt, start)
    if main:
        run_dir.mkdir(parents=True, exist_ok=True)
        save_config(cfg, run_dir / "config.json")
    acc.wait_for_everyone()

    model, opt = acc.prepare(policy, opt)
    sampler = StepBatchSampler(len(built.train_set), cfg.batch_size, cfg.seed, stop, start, rank, world)
    loader = torch.utils.data.DataLoader(
        built.train_set,
        batch_sampler=sampler,
        num_workers=cfg.data.num_workers,
        collate_fn=collate_batch,
        pin_memory=acc.device.type == "cuda",
        persistent_workers=False,
    )
    gaze_on = cfg.gaze.prior is not None and cfg.gaze.enabled
    schedule = WeightSchedule(
        cfg.gaze.weight, cfg.gaze.schedule, cfg.gaze.warmup_steps, total, cfg.gaze.final_frac
    )
    spec = policy.gaze_probe_spec(built.gaze_camera, cfg.gaze.layers) if gaze_on else None
    eval_sets = {"val": built.val_set} if built.val_set is not None else {"train": built.train_set}
    eval_batches = {k: fixed_batch(ds, cfg.eval_batch_size) for k, ds in eval_sets.items()}
    logger = (
        make_logger(cfg.logger, run_dir, to_dict(cfg), cfg.wandb_project)
        if main
        else make_logger("none", run_dir, {})
    )
    bar = tqdm(
        total=stop, initial=start, desc="train", disable=not (main and cfg.progress), dynamic_ncols=True
    )
    autocast = acc.autocast if cfg.mixed_precision != "no" else contextlib.nullcontext
    if main:
        log.info(
            "policy %s: %d parameters; %d training samples; %d process(es) on %s; gaze %s",
            cfg.policy_type,
            policy.num_parameters(),
            len(built.train_set),
            world,
            acc.device,
            f"{cfg.gaze.prior} on {built.gaze_camera}" if gaze_on else "off",
        )

    def eval_policy() -> nn.Module:
        return ema.model if ema is not None else policy

    def checkpoint(step: int) -> Path | None:
        path = None
        if main:
            state = {
                "steps": total,
                "epoch": sampler.epoch_of(step),
                "config": to_dict(cfg),
                "ema_updates": ema.updates if ema is not None else 0,
            }
            path = save_checkpoint(
                run_dir, step, policy, opt, sched, state, ema.state_dict() if ema is not None else None
            )
            prune_checkpoints(run_dir, cfg.keep_checkpoints)
        acc.wait_for_everyone()
        return path

    acc_sums: dict[str, float] = {}
    n_acc, t_data, t_step = 0, 0.0, 0.0
    record: dict[str, Any] = {}
    last_ckpt: Path | None = None
    t_prev = time.perf_counter()
    model.train()
    for step, batch in zip(range(start, stop), loader):
        t0 = time.perf_counter()
        t_data += t0 - t_prev
        batch = {k: v.to(acc.device, non_blocking=True) for k, v in batch.items()}
        gen = step_generator(cfg.seed, step, rank, acc.device)
        w = schedule(step) if gaze_on else 0.0
        probe_ctx: Any = AttentionProbe(model, spec, adapter="tap") if gaze_on else contextlib.nullcontext()
        with probe_ctx as probe, autocast():
            loss, info = model(batch, generator=gen, shift=cfg.shift)
        terms = {"loss/action": float(loss.detach())}
        if probe is not None:
            kl, ginfo = gaze_loss(
                batch["gaze"],
                probe.distribution(),
                batch["gaze_valid"],
                cfg.gaze.divergence,
                cfg.gaze.loss_eps,
            )
            if w > 0:  # weight 0 logs the KL but leaves the graph (and so the update) exactly the baseline's
                loss = loss + w * kl
            terms.update(
                {
                    "loss/gaze_kl": float(kl.detach()),
                    "gaze/patch_mass": float(probe.patch_mass().mean()),
                    **ginfo,
                }
            )
        if not torch.isfinite(loss):
            raise FloatingPointError(f"non-finite loss at step {step}: {terms}")
        opt.zero_grad(set_to_none=True)
        acc.backward(loss)
        grad_norm = (
            acc.clip_grad_norm_(model.parameters(), cfg.optim.grad_clip) if cfg.optim.grad_clip > 0 else None
        )
        opt.step()
        cur_lr = sched.get_last_lr()[0]  # the LR this update used
        sched.step()
        if ema is not None:
            ema.update(policy)
        terms["loss"] = float(loss.detach())
        if grad_norm is not None:
            terms["grad_norm"] = float(grad_norm)
        for k, v in terms.items():
            acc_sums[k] = acc_sums.get(k, 0.0) + v
        n_acc += 1
        t_prev = time.perf_counter()
        t_step += t_prev - t0
        done = step + 1
        bar.update(1)

        is_log = done % cfg.log_every == 0 or done == stop
        is_eval = done % cfg.eval_every == 0 or done == stop
        if is_log or is_eval:
            record = {"step": done, "epoch": round(sampler.epoch_of(done), 4), "lr": cur_lr}
            if gaze_on:
                record["gaze/weight"] = w  # the current weight (not an interval mean)
            if n_acc:
                means = [acc_sums[k] / n_acc for k in sorted(acc_sums)]
                if world > 1:  # average the interval means over processes
                    means = acc.reduce(
                        torch.tensor(means, dtype=torch.float64, device=acc.device), "mean"
                    ).tolist()
                record.update(dict(zip(sorted(acc_sums), means)))
                record.update(
                    {
                        "time/step_s": t_step / n_acc,
                        "time/data_s": t_data / n_acc,
                        "throughput/samples_per_s": cfg.batch_size * n_acc / max(t_step + t_data, 1e-9),
                    }
                )
            acc_sums, n_acc, t_data, t_step = {}, 0, 0.0, 0.0
        if is_eval:
            if main:
                for name, eb in eval_batches.items():
                    record.update(evaluate_batch(eval_policy(), eb, cfg, built.gaze_camera, name))
                for cb in callbacks:
                    ep = eval_policy()
                    ep.eval()
                    ep.reset()
                    record.update(cb(done, ep) or {})
                    ep.reset()
                    policy.train()
            acc.wait_for_everyone()
        if (is_log or is_eval) and main:
            metrics.write(record)
            logger.log(record, done)
            bar.set_postfix(
                {
                    k.split("/")[-1]: f"{record[k]:.4f}"
                    for k in ("loss/action", "loss/gaze_kl", "val/gaze_kl")
                    if k in record
                }
            )
        if done % cfg.save_every == 0 or done == stop:
            last_ckpt = checkpoint(done)
        t_prev = time.perf_counter()
    bar.close()
    logger.close()
    acc.wait_for_everyone()
    acc.end_training()
    if last_ckpt is None and ckpt is not None and start >= stop:
        last_ckpt = ckpt  # nothing left to train: the resumed checkpoint is the result
    return {
        "run_dir": run_dir,
        "step": max(stop, start),
        "checkpoint": last_ckpt,
        "metrics": record,
        "main": main,
    }


def main(argv: list[str] | None = None) -> int:
    from gazereg.runtime.config import parse

    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    cfg = parse(
        PRESETS, sys.argv[1:] if argv is None else argv, prog="gazereg train", description=__doc__ or ""
    )
    result = train(cfg)
    if result["main"] and result["metrics"]:
        summary = {k: v for k, v in result["metrics"].items() if not k.startswith("time/")}
        print(
            json.dumps(
                {"run_dir": str(result["run_dir"]), "checkpoint": str(result["checkpoint"]), **summary}
            )
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
