"""Does `torch.compile` pay for the reference VLA's training step on this CPU? Printed as JSON.

    python benchmarks/bench_compile.py [--batch 32] [--steps 12] [--rounds 3] [--threads 1] [--quick]

The step of benchmarks/bench_train.py's `default` path (what `gazereg train` runs: explicit-softmax
attention, fused AdamW, autocast in the precision `resolve_precision` picks here), for the baseline and the
gaze term, eager against the same policy compiled in place (`nn.Module.compile()`, inductor, default mode)
and against regional compilation (each transformer block compiled, the stem, embeddings and head eager):
- the seconds of the first steps (compilation included) and the median ms per step after them, paths
  interleaved over rounds so a shared CPU slows both alike;
- `speedup_vs_eager` per compiled path and term (> 1: compiling pays);
- the graph breaks dynamo counted while compiling, by reason (the attention probe's `tap()` reads a
  ContextVar that dynamo cannot trace, so each attention layer is cut in two).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import torch
from _timing import machine_info
from bench_train import TRAIN_CFG, Trainer, interleaved_ms, make_dataset, make_store, train_step

from gazereg.data.dataset import StepBatchSampler

TERMS = ("baseline", "gaze")
PATHS = ("eager", "compiled", "compiled_blocks")


def build(path: str) -> Trainer:
    tr = Trainer.for_path("default")
    if path == "compiled":
        tr.policy.compile()
    elif path == "compiled_blocks":
        for block in tr.policy.blocks:
            block.compile()
    return tr


def graph_breaks() -> dict[str, int]:
    from torch._dynamo.utils import counters

    return {reason[:120]: n for reason, n in counters["graph_break"].items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument(
        "--steps", type=int, help="timed steps per path and term per round (default 12, --quick 3)"
    )
    ap.add_argument("--rounds", type=int, help="default 3, --quick 1")
    ap.add_argument("--warmup", type=int, default=3, help="untimed first steps (compilation happens here)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (the experiment trains on one)")
    ap.add_argument("--quick", action="store_true", help="smoke run: fewer steps and rounds")
    args = ap.parse_args()
    steps, rounds = args.steps or (3 if args.quick else 12), args.rounds or (1 if args.quick else 3)
    torch.set_num_threads(args.threads)
    out: dict = {
        "machine": machine_info(precision=TRAIN_CFG.mixed_precision, note="shared CPU: timings are noisy"),
        "batch": args.batch,
        "torch_compile": {"backend": "inductor", "mode": "default"},
    }
    store = make_store(Path(tempfile.mkdtemp()) / "store")
    trainers = {(p, t): build(p) for p in PATHS for t in TERMS}
    ds = make_dataset(store, trainers[("eager", "baseline")].policy)
    sampler = StepBatchSampler(len(ds), args.batch, 0, 10**6)
    batches = [ds.__getitems__(sampler.batch_indices(i)) for i in range(steps)]

    first_s = {}
    for (p, t), tr in trainers.items():
        t0 = time.perf_counter()
        for i in range(args.warmup):
            train_step(tr, batches[i % len(batches)], t, i)
        first_s[f"{p}/{t}"] = round(time.perf_counter() - t0, 2)
    ms = {f"{p}/{t}": round(v, 2) for (p, t), v in interleaved_ms(trainers, batches, rounds).items()}
    out["first_steps_s"] = first_s
    out["step_ms_median"] = ms
    out["speedup_vs_eager"] = {
        p: {t: round(ms[f"eager/{t}"] / ms[f"{p}/{t}"], 3) for t in TERMS} for p in PATHS[1:]
    }
    out["graph_breaks"] = graph_breaks()
    out["machine"]["load_avg_after"] = [round(x, 2) for x in os.getloadavg()]
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
