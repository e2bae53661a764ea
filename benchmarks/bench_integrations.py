"""Training-step cost of gaze capture in transformers models: forward + backward of tiny PI0 and SmolVLM with
and without the GazeRegularizer (and, for reference, the model switched to eager attention with
output_attentions=True, the naive way to get differentiable attention).

    python benchmarks/bench_integrations.py [--steps 20] [--threads 1]

Prints one JSON object. The three variants are interleaved step by step so that load from other processes on
a shared CPU hits them alike; medians and inter-quartile ranges are reported, in milliseconds per step.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import torch
from _timing import machine_info

from gazereg.integrations.transformers import GazeRegularizer

# the tiny random models of the integration tests (built from configs, no hub access)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "integrations"))
from tiny_models import tiny_batch, tiny_model  # noqa: E402

SIZES = {
    # family: tiny_model kwargs; 2 cameras each
    "pi0": dict(n_layers=4, image_size=64, patch_size=8, hidden=64, chunk_size=10),  # 64 tokens/camera
    "smolvlm": dict(n_layers=4, image_size=128, patch_size=8, hidden=64),  # 256 patches -> 64 tokens/camera
}


def _quantiles(xs: list[float]) -> dict[str, float]:
    q = statistics.quantiles(xs, n=4)
    return {"median_ms": 1e3 * statistics.median(xs), "q1_ms": 1e3 * q[0], "q3_ms": 1e3 * q[2]}


def bench(family: str, steps: int, batch: int) -> dict:
    model = tiny_model(family, **SIZES[family]).train()
    eager = tiny_model(family, attn_implementation="eager", **SIZES[family]).train()
    data = tiny_batch(model, batch=batch, n_cameras=2, text=16)
    reg = GazeRegularizer(model, ["front", "wrist"], weight=0.1)  # default layers: the second half
    gaze = {c: torch.full((batch, g.n_patches), 1.0 / g.n_patches) for c, g in reg.cameras.items()}

    def plain():
        model(**data).loss.backward()

    def captured():
        with reg:
            out = model(**data)
        term, _ = reg.loss(gaze)
        (out.loss + term).backward()

    def eager_attn():
        out = eager(**data, output_attentions=True)
        att = torch.stack([a.mean(1) for a in out.attentions[2:]]).sum()  # stands in for selecting rows
        (out.loss + 0 * att).backward()

    variants = {"sdpa": plain, "sdpa+gaze_capture": captured, "eager+output_attentions": eager_attn}
    times: dict[str, list[float]] = {k: [] for k in variants}
    for i in range(steps + 3):
        for name, fn in variants.items():
            model.zero_grad(set_to_none=True)
            eager.zero_grad(set_to_none=True)
            t = time.perf_counter()
            fn()
            if i >= 3:  # warm-up
                times[name].append(time.perf_counter() - t)
    res = {k: _quantiles(v) for k, v in times.items()}
    base = res["sdpa"]["median_ms"]
    for k in res:
        res[k]["ratio_to_sdpa"] = res[k]["median_ms"] / base
    seq = data["input_ids"].shape[1] + (model.config.chunk_size + 1 if family == "pi0" else 0)
    return {
        "model": type(model).__name__,
        "size": SIZES[family],
        "batch": batch,
        "tokens": seq,
        "captured_layers": list(reg.layers),
        "params_M": sum(p.numel() for p in model.parameters()) / 1e6,
        "step": res,
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    out = {
        "machine": machine_info(
            precision="no",  # float32 throughout
            host=platform.node(),
            cpu_count=os.cpu_count(),
            load_avg_1m_start=os.getloadavg()[0],
            python=sys.version.split()[0],
        ),
        "steps": args.steps,
    }
    import transformers

    out["machine"]["transformers"] = transformers.__version__
    for fam in SIZES:
        print(f"benchmarking {fam} ...", file=sys.stderr, flush=True)
        out[fam] = bench(fam, args.steps, args.batch)
    out["machine"]["load_avg_1m_end"] = os.getloadavg()[0]
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
