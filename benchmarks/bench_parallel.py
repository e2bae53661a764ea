"""How to spend the machine's cores on several fine-tuning runs: one run at a time on every core, or runs side by
side on fewer threads each (`gazereg experiment --parallel P --threads-per-run T`); printed as JSON.

    python benchmarks/bench_parallel.py [--layouts 1x2 2x1 1x1] [--steps 60] [--batch 32]
    python benchmarks/bench_parallel.py --markdown docs/benchmarks/parallel.json   # its table, for docs

Each layout PxT starts P fresh processes at once, each training the `ml45` preset's policy (the study's, 192x4)
on T torch threads as `gazereg train` steps it without gaze, on a synthetic store (no simulator): a few warm-up
steps, then `--steps` timed steps. Per layout: each process's steps per second and their sum, the machine's
throughput, and that throughput against the first layout's. A layout that oversubscribes the cores (P x T above
them) is measured as asked. Only the step is timed: data loading, evaluation and checkpoints are not.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
from _timing import machine_info, machine_line, print_markdown
from bench_pretrain_size import TRAIN_CFG, build, step
from bench_train import make_store

from gazereg.data.dataset import EpisodeDataset, StepBatchSampler
from gazereg.data.store import EpisodeStore

WARMUP = 3


def parse_layout(text: str) -> tuple[int, int]:
    """`PxT` -> (processes, threads each), both >= 1."""
    procs, _, threads = text.partition("x")
    p, t = int(procs), int(threads)
    if p < 1 or t < 1:
        raise ValueError(f"a layout is PxT with P, T >= 1, got {text!r}")
    return p, t


def worker(threads: int, steps: int, batch: int, store_root: Path) -> float:
    """Train `steps` timed steps (after `WARMUP`) on `threads` threads on the store at `store_root`; returns
    steps per second."""
    torch.set_num_threads(threads)
    policy, opt = build(192, 4)
    store = EpisodeStore(store_root)
    ds = EpisodeDataset(
        store,
        store.indices(),
        ["corner2"],
        policy.config.chunk,
        policy.tokenizer,
        geometry=policy.geometry("corner2"),
    )
    sampler = StepBatchSampler(len(ds), batch, 0, WARMUP + steps)
    batches = [ds.__getitems__(sampler.batch_indices(i)) for i in range(WARMUP + steps)]
    for i in range(WARMUP):
        step(policy, opt, batches[i], i)
    t0 = time.perf_counter()
    for i in range(WARMUP, WARMUP + steps):
        step(policy, opt, batches[i], i)
    return steps / (time.perf_counter() - t0)


def measure(layout: tuple[int, int], steps: int, batch: int, store_root: Path) -> dict:
    """Start the layout's processes together; each prints its steps per second."""
    procs, threads = layout
    cmd = [sys.executable, __file__, "--worker", str(threads), "--steps", str(steps), "--batch", str(batch)]
    cmd += ["--store", str(store_root)]
    env = {**os.environ, "OMP_NUM_THREADS": str(threads)}
    running = [subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env=env) for _ in range(procs)]
    rates = []
    for p in running:
        out, _ = p.communicate()
        if p.returncode != 0:
            raise RuntimeError(f"a {procs}x{threads} worker failed (exit {p.returncode})")
        rates.append(float(out.strip().splitlines()[-1]))
    return {
        "layout": f"{procs}x{threads}",
        "processes": procs,
        "threads_each": threads,
        "steps_per_s_each": [round(r, 3) for r in rates],
        "steps_per_s_total": round(sum(rates), 3),
    }


def markdown_table(result: dict, source: str) -> str:
    lines = [
        f"{machine_line(result['machine'])}; the `ml45` policy, {result['steps']} timed steps of batch "
        f"{result['batch']} per process; from `{source}`. Steps per second of each process, their sum, and the "
        f"sum against {result['rows'][0]['layout']}:",
        "",
        "| layout (processes x threads) | steps/s each | steps/s total | total vs first |",
        "|---|---|---|---|",
    ]
    for r in result["rows"]:
        each = ", ".join(f"{x:.2f}" for x in r["steps_per_s_each"])
        lines.append(f"| {r['layout']} | {each} | {r['steps_per_s_total']:.2f} | {r['vs_first']:.2f}x |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--layouts", nargs="+", default=["1x2", "2x1", "1x1"], help="PxT: P processes of T threads"
    )
    ap.add_argument("--steps", type=int, default=60, help="timed steps per process")
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--markdown", type=Path, metavar="JSON", help="measure nothing: print a JSON's table")
    ap.add_argument("--worker", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--store", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.markdown is not None:
        return print_markdown(args.markdown, markdown_table, "bench_parallel.py")
    if args.worker is not None:
        print(worker(args.worker, args.steps, args.batch, args.store))
        return 0
    try:
        layouts = [parse_layout(s) for s in args.layouts]
    except ValueError as e:
        print(f"bench_parallel.py: error: --layouts: {e}", file=sys.stderr)
        return 2
    root = Path(tempfile.mkdtemp()) / "store"
    make_store(root)
    rows = [measure(layout, args.steps, args.batch, root) for layout in layouts]
    for r in rows:
        r["vs_first"] = round(r["steps_per_s_total"] / rows[0]["steps_per_s_total"], 3)
    out = {
        "machine": machine_info(TRAIN_CFG.mixed_precision),
        "steps": args.steps,
        "batch": args.batch,
        "rows": rows,
    }
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
