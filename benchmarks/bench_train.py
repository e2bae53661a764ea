"""Training cost of the gaze regularizer on the tiny preset (CPU), printed as JSON.

    python benchmarks/bench_train.py [--batch 32] [--steps 15] [--rounds 3] [--threads 2]

Measures, on a synthetic 96 px store (no simulator needed):
- step time (forward + backward + AdamW + clipping, batch 32) for the baseline, the gaze term through the
  attention probe (last 2 layers), and a naive gaze term that materialises every layer's attention
  probabilities (like `output_attentions=True`); modes are interleaved over several rounds and the median
  per-step time is reported, so a noisy shared CPU affects all modes alike;
- activation memory: bytes saved for backward in one step (saved-tensor hooks), and the peak RSS of a fresh
  process running each mode;
- inference latency of `select_action` (a chunk predicted every call) for a baseline and a gaze-trained
  checkpoint (same architecture, so the ratio should be ~1.00);
- data loading: samples/s of the training DataLoader (in memory and memory-mapped) against training samples/s.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from gazereg.attention.probe import AttentionProbe
from gazereg.data.dataset import EpisodeDataset, StepBatchSampler, collate_batch
from gazereg.data.store import Episode, EpisodeStore
from gazereg.losses import gaze_loss
from gazereg.policies.vla import Tokenizer, VLAConfig, VLAPolicy

MODES = ("baseline", "gaze_probe", "naive_all_layers")


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
        heat = np.exp(
            -(((xs + 0.5) / 64 - uv[:, 0, None, None]) ** 2 + ((ys + 0.5) / 64 - uv[:, 1, None, None]) ** 2)
            / 0.005
        )
        store.write_prior(
            "bench", e, (heat / heat.sum((1, 2), keepdims=True)).astype(np.float32), np.ones(length, bool)
        )
    store.write_prior_info("bench", {"camera": "corner2"})
    return store


def make_policy(seed: int = 0) -> VLAPolicy:
    torch.manual_seed(seed)
    base = VLAConfig()
    tok = Tokenizer.build(["reach the goal"], max_len=base.max_text_len)
    cfg = VLAConfig(
        cameras=("corner2",), camera_hw=((96, 96),), state_dim=4, action_dim=4, vocab_size=tok.vocab_size
    )
    return VLAPolicy(cfg, tok)


def make_dataset(store: EpisodeStore, policy: VLAPolicy, in_memory: bool = True) -> EpisodeDataset:
    return EpisodeDataset(
        store,
        store.indices(),
        ["corner2"],
        policy.config.chunk,
        policy.tokenizer,
        gaze_prior="bench",
        geometry=policy.geometry("corner2"),
        in_memory=in_memory,
    )


def train_step(policy: VLAPolicy, opt: torch.optim.Optimizer, batch: dict, mode: str, step: int) -> float:
    gen = torch.Generator().manual_seed(step)
    layers = policy.resolve_layers(None)
    if mode == "baseline":
        loss, _ = policy(batch, generator=gen, shift=4)
    elif mode == "gaze_probe":
        with AttentionProbe(policy, policy.gaze_probe_spec("corner2"), adapter="tap") as probe:
            loss, _ = policy(batch, generator=gen, shift=4)
        kl, _ = gaze_loss(batch["gaze"], probe.distribution(), batch["gaze_valid"])
        loss = loss + 0.1 * kl
    else:  # every layer's (B, H, T, T) probabilities materialised, then the same reduction
        loss, info = policy(batch, generator=gen, shift=4, output_attentions=True)
        q, k = policy.action_positions(), policy.patch_positions("corner2")
        rows = torch.stack([info["attentions"][i][:, :, q, k].mean((1, 2)) for i in layers]).mean(0)
        kl, _ = gaze_loss(batch["gaze"], rows / rows.sum(-1, keepdim=True), batch["gaze_valid"])
        loss = loss + 0.1 * kl
    opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(policy.parameters(), 1.0)
    opt.step()
    return float(loss.detach())


def saved_bytes(policy: VLAPolicy, batch: dict, mode: str) -> int:
    """Bytes of tensors autograd saves for backward in one step (activation memory)."""
    total = 0

    def pack(t: torch.Tensor) -> torch.Tensor:
        nonlocal total
        total += t.numel() * t.element_size()
        return t

    opt = torch.optim.SGD(policy.parameters(), lr=0.0)
    with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
        train_step(policy, opt, batch, mode, 0)
    return total


def rss_worker(mode: str, batch_size: int, steps: int) -> dict[str, float]:
    """In a fresh process: RSS after building everything, and the peak RSS while training (sampled every
    0.5 ms by a thread), in MiB."""
    import threading

    import psutil

    proc = psutil.Process()
    store = make_store(Path(tempfile.mkdtemp()) / "s")
    policy = make_policy()
    ds = make_dataset(store, policy)
    opt = torch.optim.AdamW(policy.parameters(), 1e-3)
    sampler = StepBatchSampler(len(ds), batch_size, 0, steps)
    batches = [ds.__getitems__(sampler.batch_indices(i)) for i in range(steps)]
    train_step(policy, opt, batches[0], mode, 0)  # optimizer state allocated
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
        train_step(policy, opt, b, mode, i)
    stop.set()
    th.join()
    return {
        "rss_before_mib": before / 2**20,
        "peak_rss_mib": peak / 2**20,
        "peak_increase_mib": (peak - before) / 2**20,
    }


def rss_child(mode: str, batch_size: int, steps: int, threads: int) -> dict[str, float]:
    cmd = [
        sys.executable,
        __file__,
        "--rss-worker",
        mode,
        "--batch",
        str(batch_size),
        "--steps",
        str(steps),
        "--threads",
        str(threads),
    ]
    r = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return {k: round(v, 1) for k, v in json.loads(r.stdout).items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--steps", type=int, default=15, help="timed steps per mode per round")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-rss", action="store_true", help="skip the per-mode child processes")
    ap.add_argument("--rss-worker", choices=MODES, help=argparse.SUPPRESS)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    if args.rss_worker:
        print(json.dumps(rss_worker(args.rss_worker, args.batch, args.steps)))
        return 0
    tmp = Path(tempfile.mkdtemp())
    store = make_store(tmp / "store")
    base = make_policy()
    ds = make_dataset(store, base)
    sampler = StepBatchSampler(len(ds), args.batch, 0, 10**6)
    batches = [ds.__getitems__(sampler.batch_indices(i)) for i in range(args.steps)]

    # ----- step time, modes interleaved --------------------------------------------------------------
    policies = {m: make_policy() for m in MODES}
    opts = {m: torch.optim.AdamW(policies[m].parameters(), lr=1e-3) for m in MODES}
    for m in MODES:  # warm-up
        for i in range(3):
            train_step(policies[m], opts[m], batches[i], m, i)
    times: dict[str, list[float]] = {m: [] for m in MODES}
    for _ in range(args.rounds):
        for m in MODES:
            for i, b in enumerate(batches):
                t0 = time.perf_counter()
                train_step(policies[m], opts[m], b, m, i)
                times[m].append(time.perf_counter() - t0)
    step_ms = {m: 1000 * statistics.median(v) for m, v in times.items()}

    # ----- activation memory ---------------------------------------------------------------------------
    act = {m: saved_bytes(make_policy(), batches[0], m) / 2**20 for m in MODES}
    rss = {} if args.no_rss else {m: rss_child(m, args.batch, 5, args.threads) for m in MODES}

    # ----- inference latency of a baseline and a gaze-trained checkpoint ---------------------------------
    ckpts = {}
    for name, mode in (("baseline", "baseline"), ("gaze", "gaze_probe")):
        p = policies[mode]
        p.normalizer.set_stats(**ds.stats())
        ckpts[name] = VLAPolicy.from_pretrained(p.save_pretrained(tmp / f"ckpt_{name}"))
    obs = {"state": np.zeros(4, np.float32), "corner2": np.zeros((96, 96, 3), np.uint8)}
    lat: dict[str, list[float]] = {k: [] for k in ckpts}
    for _ in range(5):
        for name, p in ckpts.items():
            p.reset()
            p.select_action(obs, "reach the goal")  # warm
            for _ in range(20):
                p.reset()  # n_action_steps=1 anyway: every call predicts a chunk
                t0 = time.perf_counter()
                p.select_action(obs, "reach the goal")
                lat[name].append(time.perf_counter() - t0)
    lat_ms = {k: 1000 * statistics.median(v) for k, v in lat.items()}

    # ----- data loading ----------------------------------------------------------------------------------
    loader_sps = {}
    for label, in_mem in (("in_memory", True), ("mmap", False)):
        d = ds if in_mem else make_dataset(store, base, in_memory=False)
        n = 60
        dl = torch.utils.data.DataLoader(
            d, batch_sampler=StepBatchSampler(len(d), args.batch, 1, n), collate_fn=collate_batch
        )
        t0 = time.perf_counter()
        for _ in dl:
            pass
        loader_sps[label] = n * args.batch / (time.perf_counter() - t0)

    out = {
        "machine": {
            "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
            "torch": torch.__version__,
            "threads": args.threads,
            "note": "shared CPU: timings are noisy",
        },
        "policy": {
            "preset": "tiny",
            "parameters": base.num_parameters(),
            "tokens": base.n_tokens,
            "parameters_baseline_ckpt": ckpts["baseline"].num_parameters(),
            "parameters_gaze_ckpt": ckpts["gaze"].num_parameters(),
        },
        "batch": args.batch,
        "step_ms_median": {m: round(v, 2) for m, v in step_ms.items()},
        "step_ratio_gaze_vs_baseline": round(step_ms["gaze_probe"] / step_ms["baseline"], 3),
        "step_ratio_naive_vs_baseline": round(step_ms["naive_all_layers"] / step_ms["baseline"], 3),
        "activation_mib_saved_for_backward": {m: round(v, 2) for m, v in act.items()},
        "rss_fresh_process": rss,
        "inference_ms_median": {k: round(v, 3) for k, v in lat_ms.items()},
        "inference_ratio_gaze_vs_baseline": round(lat_ms["gaze"] / lat_ms["baseline"], 3),
        "loader_samples_per_s": {k: round(v) for k, v in loader_sps.items()},
        "training_samples_per_s": {m: round(args.batch / (v / 1000), 1) for m, v in step_ms.items()},
        "loader_over_training": round(
            loader_sps["in_memory"] / (args.batch / (step_ms["gaze_probe"] / 1000)), 1
        ),
        "max_rss_mib_this_process": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
