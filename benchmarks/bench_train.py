"""Training cost of the reference VLA policy (tiny preset, CPU) and of the gaze term, printed as JSON.

    python benchmarks/bench_train.py [--batch 32] [--steps 12] [--rounds 3] [--threads 1] [--no-rss] [--quick]

On a synthetic 96 px store (no simulator needed), in one run:
- median step time (forward + backward + clipping + AdamW), modes interleaved over rounds so a noisy shared CPU
  affects all alike, of three paths, each for the baseline and the gaze term through the attention probe:
  `eager_fp32` (SDPA attention, per-tensor AdamW, float32: the path before the speed work), `default` (what
  `gazereg train` does now: explicit-softmax attention, fused AdamW, autocast in the precision
  `resolve_precision` picks here) and `math_fp32` (explicit softmax, fused AdamW, float32); the default path
  also with a naive gaze term that materialises every layer's attention (`output_attentions=True`);
- matmul FLOPs per step (3x the forward's Linear, Conv2d and attention matmuls), this machine's float32 and
  bfloat16 matmul peaks on --threads threads, and the fraction of peak each path reaches;
- a coarse torch.profiler breakdown of the default step (self CPU ms per step, grouped by op name);
- activation memory (bytes saved for backward) and the peak RSS of a fresh process per gaze term;
- float32 `select_action` latency of a baseline and a gaze-trained checkpoint; DataLoader samples/s.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from _cost import efficiency, matmul_peaks, model_flops, profile_categories
from _timing import machine_info

from gazereg.attention.probe import AttentionProbe
from gazereg.data.dataset import EpisodeDataset, StepBatchSampler, collate_batch
from gazereg.data.store import Episode, EpisodeStore
from gazereg.losses import gaze_loss
from gazereg.policies.vla import Tokenizer, VLAConfig, VLAPolicy
from gazereg.training.config import PRESETS
from gazereg.training.schedule import param_groups
from gazereg.training.setup import make_optimiser, resolve_precision

TERMS = ("baseline", "gaze", "naive_all_layers")
TRAIN_CFG = resolve_precision(PRESETS["cpu"]())  # the tiny VLA on a CPU, mixed_precision "auto" resolved
BF16 = TRAIN_CFG.mixed_precision == "bf16"
PATHS = {
    "eager_fp32": {"attention": "sdpa", "fused_adamw": False, "autocast_bf16": False},
    "default": {"attention": "math", "fused_adamw": True, "autocast_bf16": BF16},
    "math_fp32": {"attention": "math", "fused_adamw": True, "autocast_bf16": False},
}
STEP_MODES = [(p, t) for p in PATHS for t in TERMS if p == "default" or t != "naive_all_layers"]


def make_store(root: Path, episodes: int = 20, length: int = 50, size: int = 96) -> EpisodeStore:
    rng = np.random.default_rng(0)
    store = EpisodeStore(root, create=True)
    ys, xs = np.mgrid[0:64, 0:64]
    for e in range(episodes):
        uv = np.linspace(rng.uniform(0.2, 0.8, 2), rng.uniform(0.2, 0.8, 2), length)
        frames = rng.integers(0, 30, (length, size, size, 3), dtype=np.uint8)
        for t, (u, v) in enumerate(uv):
            frames[t, int(v * size) - 4 : int(v * size) + 4, int(u * size) - 4 : int(u * size) + 4] = 240
        state = np.concatenate([uv, rng.normal(size=(length, 2))], 1).astype(np.float32)
        action = rng.normal(size=(length, 4)).astype(np.float32)
        store.write(Episode("reach", "reach the goal", {"corner2": frames}, state, action))
        d2 = ((xs + 0.5) / 64 - uv[:, 0, None, None]) ** 2 + ((ys + 0.5) / 64 - uv[:, 1, None, None]) ** 2
        heat = np.exp(-d2 / 0.005)
        prior = (heat / heat.sum((1, 2), keepdims=True)).astype(np.float32)
        store.write_prior("bench", e, prior, np.ones(length, bool))
    store.write_prior_info("bench", {"camera": "corner2"})
    return store


def make_policy(seed: int = 0, attention: str = "math") -> VLAPolicy:
    torch.manual_seed(seed)
    tok = Tokenizer.build(["reach the goal"], max_len=VLAConfig().max_text_len)
    data = {"cameras": ("corner2",), "camera_hw": ((96, 96),), "state_dim": 4, "action_dim": 4}
    return VLAPolicy(VLAConfig(**data, vocab_size=tok.vocab_size, attention=attention), tok)


def make_dataset(store: EpisodeStore, policy: VLAPolicy, in_memory: bool = True) -> EpisodeDataset:
    geometry = policy.geometry("corner2")
    args = (store, store.indices(), ["corner2"], policy.config.chunk, policy.tokenizer)
    return EpisodeDataset(*args, gaze_prior="bench", geometry=geometry, in_memory=in_memory)


@dataclass
class Trainer:
    """One training path: a policy, its optimiser, and whether its forward runs under bf16 autocast."""

    policy: VLAPolicy
    opt: torch.optim.Optimizer
    bf16: bool

    @classmethod
    def for_path(cls, path: str) -> Trainer:
        s = PATHS[path]
        policy = make_policy(attention=s["attention"])
        if s["fused_adamw"]:
            opt = make_optimiser(policy, TRAIN_CFG)[0]  # what `gazereg train` builds (fused on a CPU)
        else:  # the per-tensor loop (torch's CPU default before fused=True)
            o = TRAIN_CFG.optim
            groups = param_groups(policy, o.weight_decay)
            opt = torch.optim.AdamW(groups, lr=o.lr, betas=o.betas, fused=False, foreach=False)
        return cls(policy, opt, s["autocast_bf16"])


def train_step(tr: Trainer, batch: dict, term: str, step: int) -> float:
    """One step as gazereg.training.loop.step runs it: probe and autocast around the forward, the gaze KL
    outside autocast, backward, clipping, optimiser step."""
    policy, gen = tr.policy, torch.Generator().manual_seed(step)
    amp = torch.autocast("cpu", dtype=torch.bfloat16, enabled=tr.bf16)  # accelerate's autocast() on a CPU
    if term == "baseline":
        with amp:
            loss, _ = policy(batch, generator=gen, shift=4)
    elif term == "gaze":
        with AttentionProbe(policy, policy.gaze_probe_spec("corner2"), adapter="tap") as probe, amp:
            loss, _ = policy(batch, generator=gen, shift=4)
        kl, _ = gaze_loss(batch["gaze"], probe.distribution(), batch["gaze_valid"])
        loss = loss + 0.1 * kl
    else:  # every layer's (B, H, T, T) probabilities materialised, then the same reduction
        with amp:
            loss, info = policy(batch, generator=gen, shift=4, output_attentions=True)
        q, k = policy.action_positions(), policy.patch_positions("corner2")
        att = info["attentions"]
        rows = torch.stack([att[i][:, :, q, k].mean((1, 2)) for i in policy.resolve_layers(None)]).mean(0)
        kl, _ = gaze_loss(batch["gaze"], rows / rows.sum(-1, keepdim=True), batch["gaze_valid"])
        loss = loss + 0.1 * kl
    tr.opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(policy.parameters(), 1.0)
    tr.opt.step()
    return float(loss.detach())


def interleaved_ms(trainers: dict[tuple[str, str], Trainer], batches: list[dict], rounds: int) -> dict:
    """Median ms per step of every (path, term) trainer, modes interleaved over rounds so a noisy shared CPU
    affects all alike."""
    times: dict[tuple[str, str], list[float]] = {m: [] for m in trainers}
    for _ in range(rounds):
        for m, tr in trainers.items():
            for i, b in enumerate(batches):
                t0 = time.perf_counter()
                train_step(tr, b, m[1], i)
                times[m].append(time.perf_counter() - t0)
    return {m: 1000 * statistics.median(v) for m, v in times.items()}


def time_steps(batches: list[dict], rounds: int, warmup: int) -> tuple[dict, dict]:
    """Median ms per step of every (path, term) after `warmup` steps each; and the trainers."""
    trainers = {m: Trainer.for_path(m[0]) for m in STEP_MODES}
    for m, tr in trainers.items():
        for i in range(warmup):
            train_step(tr, batches[i % len(batches)], m[1], i)
    step_ms: dict[str, dict[str, float]] = {p: {} for p in PATHS}
    for (path, term), ms in interleaved_ms(trainers, batches, rounds).items():
        step_ms[path][term] = ms
    return step_ms, trainers


def profile_steps(tr: Trainer, batches: list[dict], term: str, n: int) -> dict:
    """`_cost.profile_categories` of n training steps of `tr` with `term`, after one unprofiled step."""
    train_step(tr, batches[0], term, 0)
    return profile_categories(lambda i: train_step(tr, batches[i % len(batches)], term, i), n)


def saved_bytes(policy: VLAPolicy, batch: dict, term: str, bf16: bool) -> int:
    """Bytes of tensors autograd saves for backward in one step (activation memory)."""
    total = 0

    def pack(t: torch.Tensor) -> torch.Tensor:
        nonlocal total
        total += t.numel() * t.element_size()
        return t

    tr = Trainer(policy, torch.optim.SGD(policy.parameters(), lr=0.0), bf16)
    with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
        train_step(tr, batch, term, 0)
    return total


def rss_worker(term: str, batch_size: int, steps: int) -> dict[str, float]:
    """In a fresh process (default path): RSS after building everything and the peak RSS while training
    (sampled every 0.5 ms by a thread), in MiB."""
    import threading

    import psutil

    proc = psutil.Process()
    tr = Trainer.for_path("default")
    ds = make_dataset(make_store(Path(tempfile.mkdtemp()) / "s"), tr.policy)
    sampler = StepBatchSampler(len(ds), batch_size, 0, steps)
    batches = [ds.__getitems__(sampler.batch_indices(i)) for i in range(steps)]
    train_step(tr, batches[0], term, 0)  # optimizer state allocated
    before = proc.memory_info().rss
    peak, stop = before, threading.Event()

    def sample() -> None:
        nonlocal peak
        while not stop.is_set():
            peak = max(peak, proc.memory_info().rss)
            time.sleep(0.0005)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    for i, b in enumerate(batches):
        train_step(tr, b, term, i)
    stop.set()
    th.join()
    return {
        "rss_before_mib": before / 2**20,
        "peak_rss_mib": peak / 2**20,
        "peak_increase_mib": (peak - before) / 2**20,
    }


def rss_child(term: str, batch_size: int, steps: int, threads: int) -> dict[str, float]:
    cmd = [sys.executable, __file__, "--rss-worker", term, "--batch", str(batch_size)]
    r = subprocess.run(
        [*cmd, "--steps", str(steps), "--threads", str(threads)], capture_output=True, text=True, check=True
    )
    return {k: round(v, 1) for k, v in json.loads(r.stdout).items()}


def inference_ms(ckpts: dict[str, VLAPolicy], rounds: int, calls: int) -> dict[str, float]:
    """Median float32 `select_action` ms (batch 1; n_action_steps=1, so every call predicts a chunk)."""
    obs = {"state": np.zeros(4, np.float32), "corner2": np.zeros((96, 96, 3), np.uint8)}
    lat: dict[str, list[float]] = {k: [] for k in ckpts}
    for _ in range(rounds):
        for name, p in ckpts.items():
            p.reset()
            p.select_action(obs, "reach the goal")  # warm
            for _ in range(calls):
                p.reset()
                t0 = time.perf_counter()
                p.select_action(obs, "reach the goal")
                lat[name].append(time.perf_counter() - t0)
    return {k: round(1000 * statistics.median(v), 3) for k, v in lat.items()}


def loader_rates(store: EpisodeStore, ds: EpisodeDataset, policy: VLAPolicy, batch: int, n: int) -> dict:
    rates = {}
    for label, d in (("in_memory", ds), ("mmap", make_dataset(store, policy, in_memory=False))):
        sampler = StepBatchSampler(len(d), batch, 1, n)
        t0 = time.perf_counter()
        for _ in torch.utils.data.DataLoader(d, batch_sampler=sampler, collate_fn=collate_batch):
            pass
        rates[label] = round(n * batch / (time.perf_counter() - t0))
    return rates


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--steps", type=int, help="timed steps per mode per round (default 12, --quick 3)")
    ap.add_argument("--rounds", type=int, help="default 3, --quick 2")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (the experiment trains on one)")
    ap.add_argument("--no-rss", action="store_true", help="skip the per-term child processes")
    ap.add_argument("--quick", action="store_true", help="smoke run: fewer steps, rounds and repeats")
    ap.add_argument("--rss-worker", choices=TERMS, help=argparse.SUPPRESS)
    args = ap.parse_args()
    args.steps = args.steps or (3 if args.quick else 12)
    args.rounds = args.rounds or (2 if args.quick else 3)
    return args


def report_steps(out: dict, step_ms: dict) -> None:
    d, e, m = step_ms["default"], step_ms["eager_fp32"], step_ms["math_fp32"]
    out["step_ms_median"] = {p: {t: round(v, 2) for t, v in terms.items()} for p, terms in step_ms.items()}
    out["speedup_vs_eager_fp32"] = {t: round(e[t] / d[t], 3) for t in TERMS[:2]}
    out["speedup_math_fp32_vs_eager_fp32"] = {t: round(e[t] / m[t], 3) for t in TERMS[:2]}
    out["step_ratio_gaze_vs_baseline"] = round(d["gaze"] / d["baseline"], 3)
    out["step_ratio_gaze_vs_baseline_by_path"] = {
        p: round(v["gaze"] / v["baseline"], 3) for p, v in step_ms.items()
    }
    out["step_ratio_naive_vs_baseline"] = round(d["naive_all_layers"] / d["baseline"], 3)


def report_efficiency(out: dict, step_ms: dict, policy: VLAPolicy, batch: dict, quick: bool) -> None:
    flops = model_flops(policy, batch)
    peaks = matmul_peaks((256, 512, 1024), 0.05 if quick else 0.25)
    out["model_gflop_per_step"] = round(flops["model_gflop_per_step"], 3)
    out["flops"] = {k: round(v, 4) for k, v in flops.items()}
    out["flops"]["note"] = "matmuls only (Linear, Conv2d, attention's bmm); step = 3x forward"
    out["matmul_peak_gflops"] = peaks
    bf16_paths = {p for p, v in PATHS.items() if v["autocast_bf16"]}
    out["achieved_gflops"], out["fraction_of_peak"] = efficiency(
        step_ms, flops["model_gflop_per_step"], peaks, bf16_paths
    )


def main() -> int:
    args = parse_args()
    torch.set_num_threads(args.threads)
    if args.rss_worker:
        print(json.dumps(rss_worker(args.rss_worker, args.batch, args.steps)))
        return 0
    q, out = (
        args.quick,
        {
            "machine": machine_info(
                precision=TRAIN_CFG.mixed_precision, note="shared CPU: timings are noisy"
            ),
            "batch": args.batch,
            "paths": PATHS,
        },
    )
    tmp = Path(tempfile.mkdtemp())
    store = make_store(tmp / "store")
    base = make_policy()
    ds = make_dataset(store, base)
    sampler = StepBatchSampler(len(ds), args.batch, 0, 10**6)
    batches = [ds.__getitems__(sampler.batch_indices(i)) for i in range(args.steps)]
    out["policy"] = {"preset": "tiny", "parameters": base.num_parameters(), "tokens": base.n_tokens}

    step_ms, trainers = time_steps(batches, args.rounds, warmup=1 if q else 2)
    report_steps(out, step_ms)
    report_efficiency(out, step_ms, base, batches[0], q)
    n_prof = 2 if q else 5
    out["profile_default_ms_per_step"] = {
        t: profile_steps(trainers[("default", t)], batches, t, n_prof) for t in TERMS[:2]
    }

    act = {t: saved_bytes(make_policy(), batches[0], t, BF16) / 2**20 for t in TERMS}
    out["activation_mib_saved_for_backward_default"] = {t: round(v, 2) for t, v in act.items()}
    rss = {} if args.no_rss else {t: rss_child(t, args.batch, 5, args.threads) for t in TERMS}
    out["rss_fresh_process_default"] = rss

    ckpts = {}
    for term in TERMS[:2]:  # the default path's policies after training, saved and loaded back
        p = trainers[("default", term)].policy
        p.normalizer.set_stats(**ds.stats())
        ckpts[term] = VLAPolicy.from_pretrained(p.save_pretrained(tmp / f"ckpt_{term}"))
    out["inference_ms_median_fp32"] = lat = inference_ms(ckpts, 2 if q else 5, 10 if q else 20)
    out["inference_ratio_gaze_vs_baseline"] = round(lat["gaze"] / lat["baseline"], 3)

    out["loader_samples_per_s"] = loader = loader_rates(store, ds, base, args.batch, 20 if q else 60)
    train_sps = {t: args.batch * 1000 / ms for t, ms in step_ms["default"].items()}
    out["training_samples_per_s_default"] = {t: round(v, 1) for t, v in train_sps.items()}
    out["loader_over_training"] = round(loader["in_memory"] / train_sps["gaze"], 1)
    out["machine"]["load_avg_after"] = [round(x, 2) for x in os.getloadavg()]
    out["max_rss_mib_this_process"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
