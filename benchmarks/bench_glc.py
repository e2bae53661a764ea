"""GLC forward speed on this CPU: clips/s, frames/s, FLOPs per clip, and the fraction of matmul peak.

    python benchmarks/bench_glc.py [--threads 2] [--repeat 5] [--skip-full]

FLOPs are counted with torch.utils.flop_counter.FlopCounterMode (matmuls, convolutions and attention;
one multiply-add = 2 FLOPs; norms, GELU and softmax are not counted). The CPU flash-attention kernel
that scaled_dot_product_attention uses is not in the counter's table, so its formula is registered here.
"Peak" is the measured float32 GFLOP/s of a large square matmul on the same threads, so
`fraction_of_matmul_peak = FLOPs/clip * clips/s / peak`. Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os

import torch
from _timing import machine_info, median_time
from torch.utils.flop_counter import FlopCounterMode, sdpa_flop_count

from gazereg.gaze.glc import GLC, GLCConfig
from gazereg.gaze.glc.targets import gaze_target_maps
from gazereg.training.glc import GLCTrainConfig, glc_kl_loss, make_optimizer


def _sdpa_cpu_flops(q_shape, k_shape, v_shape, *args, out_shape=None, **kwargs) -> int:
    return sdpa_flop_count(q_shape, k_shape, v_shape)


_CUSTOM_FLOPS = {torch.ops.aten._scaled_dot_product_flash_attention_for_cpu: _sdpa_cpu_flops}


def matmul_peak_gflops(n: int = 2048, repeat: int = 5) -> float:
    a, b = torch.randn(n, n), torch.randn(n, n)
    t = median_time(lambda: torch.mm(a, b), repeat=repeat, warmup=2)
    return 2 * n**3 / t / 1e9


def flops_per_clip(model: GLC) -> dict[str, float]:
    x = torch.randn(1, *model.cfg.input_shape)
    with torch.no_grad(), FlopCounterMode(display=False, custom_mapping=_CUSTOM_FLOPS) as fc:
        model(x)
    by_op = {str(k).rsplit(".", 1)[-1]: float(v) for k, v in fc.get_flop_counts()["Global"].items()}
    return {"total": float(fc.get_total_flops()), **by_op}


def bench_forward(name: str, cfg: GLCConfig, batch: int, repeat: int, peak: float) -> dict:
    torch.manual_seed(0)
    model = GLC(cfg).eval()
    x = torch.randn(batch, *cfg.input_shape)
    with torch.inference_mode():
        t = median_time(lambda: model(x), repeat=repeat)
    flops = flops_per_clip(model)
    clips_s = batch / t
    achieved = flops["total"] * clips_s / 1e9
    return {
        "config": name,
        "input": [batch, *cfg.input_shape],
        "output": [batch, 1, *cfg.output_shape],
        "params_M": round(model.num_parameters() / 1e6, 3),
        "seconds_per_batch": round(t, 4),
        "clips_per_s": round(clips_s, 3),
        "frames_per_s": round(clips_s * cfg.num_frames, 2),
        "gflops_per_clip": round(flops["total"] / 1e9, 3),
        "gflops_by_op": {k: round(v / 1e9, 3) for k, v in flops.items() if k != "total"},
        "achieved_gflops_s": round(achieved, 2),
        "fraction_of_matmul_peak": round(achieved / peak, 3),
    }


def bench_train_step(cfg: GLCConfig, batch: int, repeat: int) -> dict:
    torch.manual_seed(0)
    model = GLC(cfg).train()
    opt = make_optimizer(model, GLCTrainConfig())
    x = torch.randn(batch, *cfg.input_shape)
    target = gaze_target_maps(torch.rand(batch, cfg.output_shape[0], 2), None, cfg.output_shape[1:])

    def step():
        loss = glc_kl_loss(model(x), target)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()

    t = median_time(step, repeat=repeat)
    return {"batch": batch, "seconds_per_step": round(t, 4), "clips_per_s": round(batch / t, 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--skip-full", action="store_true", help="only the small preset")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    peak = matmul_peak_gflops()
    results = {
        "machine": machine_info(
            precision="no", cpu_count=os.cpu_count(), matmul_peak_gflops_s=round(peak, 2)
        ),  # float32 forward and training steps
        "forward": [],
    }
    if not args.skip_full:
        results["forward"].append(bench_forward("full", GLCConfig.full(), 1, args.repeat, peak))
    results["forward"].append(bench_forward("small", GLCConfig.small(), 8, args.repeat, peak))
    results["train_step_small"] = bench_train_step(GLCConfig.small(), 8, args.repeat)
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
