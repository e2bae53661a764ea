"""Gaze-prior throughput of the `glc` source vs the GLC model's pure forward time on the same clips.

    python benchmarks/bench_glc_priors.py [--threads 2] [--repeat 3] [--skip-full] [--skip-small] [--frames-small 96] [--frames-full 24]

For each config (small, full; random weights) and mode (average = the default efficient mode, centre = one
clip per frame) one synthetic episode of 96x96 frames goes through what `gazereg priors` does per episode:
the source (clip planning, resize/crop/normalise, batched forward, softmax, per-frame averaging, resize to
64x64, renormalisation) and the temporal aggregation (past=2, future=2). The reference is the model's
forward alone on the same number of clips in the same batch sizes, on a ready input tensor. Source and
reference runs alternate, medians are reported; `overhead_ratio = source / forward` (target: <= 2).
Prints one JSON object. The CPU may be shared: absolute timings are noisy, the ratio less so.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import torch
from _timing import machine_info

from gazereg.aggregation import AggregationConfig, aggregate
from gazereg.gaze.glc.data import synthetic_gaze_episode
from gazereg.gaze.sources.glc import GLCGaze, GLCParams


def bench(
    config: str, mode: str, frames: int, repeat: int, batch_size: int = 8, stride: int = 2, hop: int = 4
) -> dict:
    src = GLCGaze(GLCParams(Path("random"), config, stride=stride, mode=mode, hop=hop, batch_size=batch_size))
    ep = synthetic_gaze_episode(length=frames, size=96, camera="cam", seed=0)
    n = len(src.plan(frames)[0])
    sizes = [min(batch_size, n - s) for s in range(0, n, batch_size)]
    inputs = {b: torch.randn(b, *src.cfg.input_shape) for b in set(sizes)}
    agg = AggregationConfig(past=2, future=2)

    def run_source() -> None:
        heat, valid = src(ep, "cam", (64, 64))
        aggregate(torch.from_numpy(heat), torch.from_numpy(valid), agg)

    def run_forward() -> None:
        with torch.inference_mode():
            for b in sizes:
                src.model(inputs[b])

    run_source()  # warm-up (allocator, kernels)
    run_forward()
    t_src, t_fwd = [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        run_source()
        t_src.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        run_forward()
        t_fwd.append(time.perf_counter() - t0)
    s, f = statistics.median(t_src), statistics.median(t_fwd)
    return {
        "config": config,
        "mode": mode,
        "stride": stride,
        "hop": hop if mode == "average" else None,
        "batch_size": batch_size,
        "frames": frames,
        "clips": n,
        "source_seconds": round(s, 3),
        "forward_seconds": round(f, 3),
        "source_seconds_all": [round(t, 3) for t in t_src],
        "forward_seconds_all": [round(t, 3) for t in t_fwd],
        "prior_frames_per_s": round(frames / s, 2),
        "clips_per_s_source": round(n / s, 2),
        "clips_per_s_forward": round(n / f, 2),
        "overhead_ratio": round(s / f, 3),
        "within_2x": s / f <= 2.0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--frames-small", type=int, default=96)
    ap.add_argument("--frames-full", type=int, default=24)
    ap.add_argument("--skip-full", action="store_true")
    ap.add_argument("--skip-small", action="store_true")
    args = ap.parse_args()
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    results = []
    if not args.skip_small:
        results.append(bench("small", "average", args.frames_small, args.repeat))
        results.append(bench("small", "centre", args.frames_small, args.repeat))
    if not args.skip_full:
        results.append(bench("full", "average", args.frames_full, max(1, args.repeat - 1)))
    out = {
        "benchmark": "glc_priors",
        "machine": machine_info(precision="no"),  # float32 GLC inference
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "cpu": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "load_average_1m_at_end": round(os.getloadavg()[0], 2),
        "results": results,
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
