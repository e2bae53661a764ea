"""What a training step costs in arithmetic (imported as `_cost` by bench_train.py: scripts run from this folder):
the matmul FLOPs of a forward, this machine's matmul peaks, the fraction of peak a step reaches, and a
torch.profiler breakdown by op category."""

from __future__ import annotations

import time
from collections.abc import Callable

import torch

OPS = {  # profiler op (aten::<op>) -> category; also attention: *scaled_dot_product*; optimizer: see op_category
    "linear_matmul": ("mm", "addmm"),
    "attention": ("bmm", "_softmax", "softmax", "_softmax_backward_data"),
    "conv_stem": ("conv2d", "convolution", "_convolution", "convolution_backward", "mkldnn_convolution"),
    "casts_copies": ("copy_", "_to_copy", "to"),
}
OP_CATEGORY = {f"aten::{op}": cat for cat, ops in OPS.items() for op in ops}
CATEGORIES = (*OPS, "optimizer", "other")


def model_flops(policy: torch.nn.Module, batch: dict) -> dict[str, float]:
    """GFLOP of one training forward's matmuls (hooks on every Linear / Conv2d; attention's two batched
    matmuls from the config) and of a step (forward + backward = 3x)."""
    flops = {"linear": 0, "conv": 0}

    def count(m: torch.nn.Module, _inp: object, out: torch.Tensor) -> None:
        if isinstance(m, torch.nn.Linear):
            flops["linear"] += 2 * m.in_features * out.numel()
        else:
            kh, kw = m.kernel_size
            flops["conv"] += 2 * (m.in_channels // m.groups) * kh * kw * out.numel()

    mods = [m for m in policy.modules() if isinstance(m, torch.nn.Linear | torch.nn.Conv2d)]
    hooks = [m.register_forward_hook(count) for m in mods]
    try:
        with torch.no_grad():
            policy(batch, generator=torch.Generator().manual_seed(0), shift=4)
    finally:
        for h in hooks:
            h.remove()
    c, B, T = policy.config, batch["state"].shape[0], policy.n_tokens
    flops["attention"] = c.depth * 2 * (2 * B * c.heads * T * T * (c.dim // c.heads))
    out = {f"forward_gflop_{k}": v / 1e9 for k, v in flops.items()}
    out["forward_gflop"] = sum(flops.values()) / 1e9
    out["model_gflop_per_step"] = 3 * out["forward_gflop"]
    return out


def matmul_peaks(sizes: tuple[int, ...], min_s: float) -> dict[str, dict]:
    """GFLOP/s of square torch.mm on the current thread count per dtype (fastest call of each size)."""
    out = {}
    for dtype in (torch.float32, torch.bfloat16):
        by_size = {}
        for n in sizes:
            a, b = torch.randn(n, n).to(dtype), torch.randn(n, n).to(dtype)
            torch.mm(a, b)
            best, t_end, calls = float("inf"), time.perf_counter() + min_s, 0
            while calls < 3 or time.perf_counter() < t_end:
                t0 = time.perf_counter()
                torch.mm(a, b)
                best, calls = min(best, time.perf_counter() - t0), calls + 1
            by_size[str(n)] = round(2 * n**3 / best / 1e9, 1)
        out[str(dtype).removeprefix("torch.")] = {"best": max(by_size.values()), "by_size": by_size}
    return out


def efficiency(step_ms: dict, gflop: float, peaks: dict, bf16_paths: set[str]) -> tuple[dict, dict]:
    """Achieved GFLOP/s per (path, term) from median step times (ms) and `gflop` per step; the baseline's
    fraction of the matmul peaks (its own dtype: bfloat16 for the paths in `bf16_paths`; fp32; bf16)."""
    achieved = {p: {t: round(gflop * 1000 / ms, 1) for t, ms in v.items()} for p, v in step_ms.items()}
    fp32, bf16 = peaks["float32"]["best"], peaks["bfloat16"]["best"]
    fraction = {}
    for p, v in achieved.items():
        own = p in bf16_paths
        fraction[p] = {
            "own_dtype": "bfloat16" if own else "float32",
            "of_own_dtype_peak": round(v["baseline"] / (bf16 if own else fp32), 3),
            "of_fp32_peak": round(v["baseline"] / fp32, 3),
            "of_bf16_peak": round(v["baseline"] / bf16, 3),
        }
    return achieved, fraction


def op_category(ev: object) -> str:
    """The category of a profiler event: the optimizer's step (by its ancestors), attention, or OPS's."""
    node = ev
    while node is not None:
        if node.name.startswith("Optimizer.step") or node.name == "aten::_fused_adamw_":
            return "optimizer"
        node = node.cpu_parent
    return "attention" if "scaled_dot_product" in ev.name else OP_CATEGORY.get(ev.name, "other")


def profile_categories(step: Callable[[int], object], n: int) -> dict:
    """Self CPU ms per call of `step(i)` by category over n profiled calls (profiler overhead included) and the
    largest ops counted as "other"."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for i in range(n):
            step(i)
    totals, other = dict.fromkeys(CATEGORIES, 0.0), {}
    for ev in prof.events():
        cat = op_category(ev)
        totals[cat] += ev.self_cpu_time_total
        if cat == "other":
            other[ev.name] = other.get(ev.name, 0.0) + ev.self_cpu_time_total
    out: dict = {k: round(v / n / 1000, 2) for k, v in totals.items()}
    out["total"] = round(sum(totals.values()) / n / 1000, 2)
    top = sorted(other.items(), key=lambda kv: -kv[1])[:6]
    out["top_other_ops"] = {k: round(v / n / 1000, 2) for k, v in top}
    return out
