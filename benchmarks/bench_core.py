"""Core-library speed: prior maths throughput and the probe's cost on nn.TransformerEncoder.

    python benchmarks/bench_core.py [--threads 2]
Prints one JSON object. Timings are medians of repeated runs on this machine; compare ratios, not
absolute numbers, across machines.
"""

from __future__ import annotations

import argparse
import json

import torch
from _timing import machine_info, median_time
from torch import nn

from gazereg import (
    AggregationConfig,
    AttentionProbe,
    PatchGeometry,
    ProbeSpec,
    aggregate,
    gaze_loss,
    heatmaps_from_points,
    patch_distribution,
)


def timeit(fn) -> float:
    return median_time(fn, repeat=7, warmup=2)


def prior_maths(T: int = 500) -> dict[str, float]:
    pts = torch.rand(T, 2)
    geom = PatchGeometry(input_hw=(96, 96), patch_size=12)
    heat, valid = heatmaps_from_points(pts, (64, 64), 3.2)
    t_heat = timeit(lambda: heatmaps_from_points(pts, (64, 64), 3.2))
    t_agg = timeit(lambda: aggregate(heat, valid, AggregationConfig(past=4, future=4)))
    t_patch = timeit(lambda: patch_distribution(heat, geom, valid))
    return {
        "frames": T,
        "heatmaps_frames_per_s": T / t_heat,
        "aggregate_frames_per_s": T / t_agg,
        "patch_distribution_frames_per_s": T / t_patch,
    }


def probe_cost(batch: int = 32, tokens: int = 80, dim: int = 128, layers: int = 4) -> dict[str, float]:
    torch.manual_seed(0)
    layer = nn.TransformerEncoderLayer(dim, 4, 2 * dim, dropout=0.0, batch_first=True)
    model = nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)
    x = torch.randn(batch, tokens, dim)
    gaze = torch.softmax(torch.randn(batch, 64), -1)
    spec = ProbeSpec(queries=slice(tokens - 4, tokens), keys=slice(0, 64), layers=(layers - 2, layers - 1))

    def plain():
        model.zero_grad()
        model(x).pow(2).mean().backward()

    def probed():
        model.zero_grad()
        with AttentionProbe(model, spec) as probe:
            out = model(x)
        (out.pow(2).mean() + gaze_loss(gaze, probe.distribution())[0]).backward()

    t_plain, t_probe = timeit(plain), timeit(probed)
    return {
        "batch": batch,
        "tokens": tokens,
        "step_s_plain": t_plain,
        "step_s_probe": t_probe,
        "ratio": t_probe / t_plain,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    out = {
        "machine": machine_info(precision="no", threads=args.threads),  # float32 throughout
        "prior_maths": prior_maths(),
        "probe_on_nn_transformer": probe_cost(),
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
