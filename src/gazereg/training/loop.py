"""`gazereg train`: one training loop for baseline and gaze-regularized policies.

    gazereg train --preset cpu --data.store data/demos --run-dir runs/base
    gazereg train --preset cpu --data.store data/demos --run-dir runs/gaze --gaze.prior visuomotor
    gazereg train ... --resume                                   (continue from the newest checkpoint)
    gazereg train ... --policy.type NAME --policy.FIELD value   (another registered policy: gazereg.policies)
    accelerate launch --multi_gpu --num_processes 2 -m gazereg.training.loop --preset ci ...   (DDP; CPU: gloo)

Loss per step:  L = L_action + w(step) * mean_{valid b} KL(gaze_b || attention_b)
(the mean over the valid samples of the global batch, also with several processes: `losses.across_processes`)
where attention_b is the action queries' attention to the gaze camera's patch tokens on `gaze.layers`
(captured by an AttentionProbe, averaged over heads, queries and layers, renormalised over the patches;
`--gaze.queries language` / `both`: the instruction's real tokens' rows instead / as well) and
gaze_b the stored prior mapped onto the policy's patch grid once when the data set is built. With
`--gaze.target features` (the location control, gazereg.training.location) attention_b is replaced by a
training-only head's distribution over the same patches, read from the image tokens' features; the attention
KL is then logged but not optimised.

Baseline and gaze runs share everything else: `gaze.prior` unset (or `gaze.enabled=false`) trains without the
probe; `gaze.weight=0` runs the probe and logs the KL without adding it; both reproduce the same parameters
bit for bit on the CPU with the same seed (the probe reads q and k, consumes no RNG and leaves the fused
attention untouched). Every random draw comes from generators seeded by (seed, step, rank) and the batch
order is a function of (seed, step), so `--resume` continues the exact trajectory of an uninterrupted run.

The run folder: config.json (resolved), metrics.jsonl (loss/action, loss/gaze_kl, gaze/weight, lr, timings;
with target features also loss/location_kl; val/* and align/* at every eval), checkpoints/step_XXXXXX/ (see
gazereg.training.checkpoint).

The loop (`train`): `setup` (gazereg.training.setup: accelerator, data, policy, optimiser, resume), then per
step `step` (one optimisation step), every `log_every` steps a record of the interval's means, every
`eval_every` steps `evaluate` (fixed-batch validation and callbacks), every `save_every` steps `checkpoint`.
The policy is used only through the Policy interface (gazereg.policies.base).
"""

from __future__ import annotations

import contextlib
import json
import logging
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from gazereg.attention.probe import AttentionProbe
from gazereg.losses import across_processes, gaze_loss
from gazereg.metrics import alignment_metrics
from gazereg.policies import Policy
from gazereg.runtime.config import parse, to_dict
from gazereg.runtime.progress import Progress
from gazereg.training.checkpoint import prune_checkpoints, save_checkpoint
from gazereg.training.config import DEFAULT_PRESET, PRESETS, TrainConfig
from gazereg.training.location import HEAD_NAME, FeatureCapture, LocationHead, average_gradients
from gazereg.training.photometric import photometric
from gazereg.training.schedule import step_generator
from gazereg.training.setup import Run, gaze_spec, setup

log = logging.getLogger(__name__)

Callback = Callable[[int, nn.Module], "dict[str, Any] | None"]
SHOWN = {
    "loss/action": "action",
    "loss/gaze_kl": "gaze_kl",
    "loss/location_kl": "location_kl",
    "val/gaze_kl": "val_gaze_kl",
}
"""the metrics the progress line shows after each logged step (metric -> name on the line)"""


@dataclass
class StepOutput:
    """What one optimisation step reports."""

    terms: dict[str, float]
    """loss, loss/action, grad_norm and (with gaze) loss/gaze_kl, gaze/* (and loss/location_kl with the
    location head): averaged over a logging interval"""
    lr: float
    """the learning rate this update used"""
    gaze_weight: float
    """the gaze weight this update used (0 without the gaze term)"""


def step(run: Run, step: int, batch: dict[str, Tensor]) -> StepOutput:
    """One optimisation step on `batch` (every random draw from the (seed, step, rank) generator)."""
    cfg, acc = run.cfg, run.acc
    batch = {k: v.to(acc.device, non_blocking=True) for k, v in batch.items()}
    gen = step_generator(cfg.seed, step, acc.process_index, acc.device)
    batch = photometric(batch, cfg.photometric, gen)  # draws nothing when off
    spec = run.batch_gaze_spec(batch)  # run.gaze_spec itself for the action queries
    w = run.gaze_weight(step) if spec is not None else 0.0
    head = run.location_head
    with contextlib.ExitStack() as stack:
        probe = capture = None
        if spec is not None:
            probe = stack.enter_context(AttentionProbe(run.model, spec, adapter="tap"))
        if head is not None and spec is not None:
            capture = stack.enter_context(FeatureCapture(run.policy, spec))
        stack.enter_context(run.autocast())
        loss, _ = run.model(batch, generator=gen, shift=cfg.shift)
    terms = {"loss/action": float(loss.detach())}
    if probe is not None:
        reg, gaze_terms = gaze_term(run, batch, probe, capture)
        if w > 0:  # weight 0 logs the KL but leaves the graph (and so the update) exactly the baseline's
            loss = loss + w * reg
        terms.update(gaze_terms)
    if not torch.isfinite(loss):
        raise FloatingPointError(f"non-finite loss at step {step}: {terms}")
    run.opt.zero_grad(set_to_none=True)
    acc.backward(loss)
    params: Any = run.model.parameters()
    if head is not None:
        average_gradients(head, acc)
        params = [*params, *head.parameters()]
    clip = cfg.optim.grad_clip
    grad_norm = acc.clip_grad_norm_(params, clip) if clip > 0 else None
    run.opt.step()
    lr = run.sched.get_last_lr()[0]
    run.sched.step()
    if run.ema is not None:
        run.ema.update(run.policy)
    terms["loss"] = float(loss.detach())
    if grad_norm is not None:
        terms["grad_norm"] = float(grad_norm)
    return StepOutput(terms, lr, w)


def gaze_term(
    run: Run, batch: dict[str, Tensor], probe: AttentionProbe, capture: FeatureCapture | None
) -> tuple[Tensor, dict[str, float]]:
    """The gaze term (before its weight) and its logged values: KL(gaze || attention); with the location
    head (`capture` given) KL(gaze || head), the attention's KL then computed on detached attention and
    logged only."""
    cfg, built = run.cfg, run.built

    def kl(dist: Tensor) -> tuple[Tensor, dict[str, float]]:
        loss, info = gaze_loss(
            batch["gaze"],
            dist,
            batch["gaze_valid"],
            cfg.gaze.divergence,
            cfg.gaze.loss_eps,
            gaze_grid=built.gaze_grid,
            attention_grid=built.attention_grid,
        )
        return across_processes(loss, batch["gaze_valid"]), info

    attention = probe.distribution()
    kl_attention, ginfo = kl(attention if capture is None else attention.detach())
    terms = {
        "loss/gaze_kl": float(kl_attention.detach()),
        "gaze/patch_mass": float(probe.patch_mass().mean()),
        **ginfo,
    }
    if capture is None or run.location_head is None:
        return kl_attention, terms
    kl_location, _ = kl(run.location_head(capture.features()))
    terms["loss/location_kl"] = float(kl_location.detach())
    return kl_location, terms


@torch.no_grad()
def evaluate_batch(
    policy: Policy,
    batch: dict[str, Tensor],
    cfg: TrainConfig,
    gaze_camera: str | None,
    prefix: str,
    grids: tuple[tuple[int, int] | None, tuple[int, int] | None] = (None, None),
    head: LocationHead | None = None,
) -> dict[str, float]:
    """Action loss and, with a prior, the attention-gaze alignment on one fixed batch (no RNG consumed).
    grids: (gaze grid, attention grid), (rows, cols) each, checked against each other by `gaze_loss`;
    head: the location control's head, whose KL is reported as {prefix}/location_kl."""
    was_training = policy.training
    policy.eval()
    gen = step_generator(cfg.seed, -1, 0, policy.device)
    out: dict[str, float] = {}
    try:
        with contextlib.ExitStack() as stack:
            probe = capture = None
            if gaze_camera is not None and "gaze" in batch:
                spec = gaze_spec(policy, gaze_camera, cfg.gaze, batch["text_mask"].to(policy.device))
                probe = stack.enter_context(AttentionProbe(policy, spec, adapter="tap"))
                capture = stack.enter_context(FeatureCapture(policy, spec)) if head is not None else None
            loss, _ = policy(batch, generator=gen)
        out[f"{prefix}/loss_action"] = float(loss)
        if probe is not None:
            dev = policy.device
            attn = probe.distribution()
            gaze, valid = batch["gaze"].to(dev), batch["gaze_valid"].to(dev)

            def kl(dist: Tensor) -> float:
                div, eps = cfg.gaze.divergence, cfg.gaze.loss_eps
                return float(
                    gaze_loss(gaze, dist, valid, div, eps, gaze_grid=grids[0], attention_grid=grids[1])[0]
                )

            out[f"{prefix}/gaze_kl"] = kl(attn)
            out[f"{prefix}/patch_mass"] = float(probe.patch_mass().mean())
            if capture is not None and head is not None:
                out[f"{prefix}/location_kl"] = kl(head(capture.features()))
            aligned = alignment_metrics(gaze.cpu(), attn.cpu(), valid.cpu())
            out.update({f"align_{prefix}/{k}": v for k, v in aligned.items()})
    finally:
        policy.train(was_training)
    return out


def evaluate(run: Run, step: int, callbacks: Sequence[Callback]) -> dict[str, Any]:
    """On the main process: the fixed-batch validation terms, then every callback's dict (callbacks get the
    evaluation policy in eval mode with its episode state reset). Every process waits for it."""
    out: dict[str, Any] = {}
    if run.main:
        built = run.built
        grids = (built.gaze_grid, built.attention_grid)
        for name, batch in run.eval_batches.items():
            policy = run.eval_policy()
            out.update(
                evaluate_batch(policy, batch, run.cfg, built.gaze_camera, name, grids, run.location_head)
            )
        for cb in callbacks:
            policy = run.eval_policy()
            policy.eval()
            policy.reset()
            out.update(cb(step, policy) or {})
            policy.reset()
            run.policy.train()
    run.acc.wait_for_everyone()
    return out


def checkpoint(run: Run, step: int) -> Path | None:
    """Save checkpoints/step_XXXXXX on the main process (and prune old ones); returns its path there."""
    path = None
    if run.main:
        ema = run.ema
        state = {
            "steps": run.cfg.steps,
            "epoch": run.sampler.epoch_of(step),
            "config": to_dict(run.cfg),
            "ema_updates": ema.updates if ema is not None else 0,
        }
        path = save_checkpoint(
            run.run_dir,
            step,
            run.policy,
            run.opt,
            run.sched,
            state,
            ema.state_dict() if ema is not None else None,
            {HEAD_NAME: run.location_head.state_dict()} if run.location_head is not None else None,
        )
        prune_checkpoints(run.run_dir, run.cfg.keep_checkpoints)
    run.acc.wait_for_everyone()
    return path


@dataclass
class Interval:
    """The logged terms and times summed since the last record."""

    sums: dict[str, float] = field(default_factory=dict)
    n: int = 0
    t_data: float = 0.0
    t_step: float = 0.0

    def add(self, terms: dict[str, float]) -> None:
        for k, v in terms.items():
            self.sums[k] = self.sums.get(k, 0.0) + v
        self.n += 1

    def means(self, run: Run) -> dict[str, float]:
        """Interval means of the terms (averaged over processes too) and the mean times per step."""
        if not self.n:
            return {}
        keys = sorted(self.sums)
        means = [self.sums[k] / self.n for k in keys]
        if run.acc.num_processes > 1:
            device = run.acc.device
            means = run.acc.reduce(torch.tensor(means, dtype=torch.float64, device=device), "mean").tolist()
        return {
            **dict(zip(keys, means)),
            "time/step_s": self.t_step / self.n,
            "time/data_s": self.t_data / self.n,
            "throughput/samples_per_s": run.cfg.batch_size * self.n / max(self.t_step + self.t_data, 1e-9),
        }


def log_record(run: Run, done: int, last: StepOutput, interval: Interval) -> dict[str, Any]:
    """The metrics record after `done` steps: epoch, LR, gaze weight and the interval's means."""
    record: dict[str, Any] = {"step": done, "epoch": round(run.sampler.epoch_of(done), 4), "lr": last.lr}
    if run.gaze_spec is not None:
        record["gaze/weight"] = last.gaze_weight  # the current weight (not an interval mean)
    return {**record, **interval.means(run)}


def log_start(run: Run) -> None:
    g = run.cfg.gaze
    on = f"{g.prior} on {run.built.gaze_camera}, target {g.target}, queries {g.queries}"
    gaze = on if run.gaze_spec is not None else "off"
    log.info(
        "policy %s: %d parameters; %d training samples; %d process(es) on %s; gaze %s",
        run.policy.name,
        run.policy.num_parameters(),
        len(run.built.train_set),
        run.acc.num_processes,
        run.acc.device,
        gaze,
    )


# ----- the loop -------------------------------------------------------------------------------------------
def train(cfg: TrainConfig, callbacks: Sequence[Callback] = ()) -> dict[str, Any]:
    """Train; returns {'run_dir', 'step', 'checkpoint', 'metrics' (the last record), 'main'}.

    callbacks: called every `eval_every` steps and at the end on the main process as cb(step, policy) with the
    evaluation policy (EMA weights if enabled) in eval mode; a returned dict is merged into the metrics."""
    run = setup(cfg)
    cfg = run.cfg
    label, show = f"train {Path(cfg.run_dir).name}", run.main and cfg.progress
    if run.main:
        log_start(run)
    interval, record, last_ckpt = Interval(), {}, None
    t_prev = time.perf_counter()
    run.model.train()
    with Progress(label, run.stop, "steps", done=run.start, enabled=show) as bar:
        for i, batch in zip(range(run.start, run.stop), run.loader):
            t0 = time.perf_counter()
            interval.t_data += t0 - t_prev
            out = step(run, i, batch)
            interval.add(out.terms)
            t_prev = time.perf_counter()
            interval.t_step += t_prev - t0
            done = i + 1
            bar.update(1)
            is_log = done % cfg.log_every == 0 or done == run.stop
            is_eval = done % cfg.eval_every == 0 or done == run.stop
            if is_log or is_eval:
                record, interval = log_record(run, done, out, interval), Interval()
            if is_eval:
                record.update(evaluate(run, done, callbacks))
            if (is_log or is_eval) and run.main:
                run.metrics.write(record)
                run.logger.log(record, done)
                bar.note(**{name: f"{record[k]:.4f}" for k, name in SHOWN.items() if k in record})
            if done % cfg.save_every == 0 or done == run.stop:
                last_ckpt = checkpoint(run, done)
            t_prev = time.perf_counter()
    return finish(run, record, last_ckpt)


def finish(run: Run, record: dict[str, Any], last_ckpt: Path | None) -> dict[str, Any]:
    """Close the logger and Accelerate; the result of `train`."""
    run.logger.close()
    run.acc.wait_for_everyone()
    run.acc.end_training()
    if last_ckpt is None and run.resumed_from is not None and run.start >= run.stop:
        last_ckpt = run.resumed_from  # nothing left to train: the resumed checkpoint is the result
    return {
        "run_dir": run.run_dir,
        "step": max(run.stop, run.start),
        "checkpoint": last_ckpt,
        "metrics": record,
        "main": run.main,
    }


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    cfg = parse(
        PRESETS,
        sys.argv[1:] if argv is None else argv,
        prog="gazereg train",
        description=__doc__ or "",
        default=DEFAULT_PRESET,
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
