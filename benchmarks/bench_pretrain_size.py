"""What a pretraining step of the reference VLA costs at candidate sizes, for sizing `gazereg pretrain`'s `ml45`
preset on the machine it runs on; printed as JSON.

    python benchmarks/bench_pretrain_size.py [--sizes 128x4 192x4 192x6 256x6] [--batch 32] [--steps 8] [--rounds 3]
    python benchmarks/bench_pretrain_size.py --markdown docs/benchmarks/pretrain_size.json   # its table, for docs

Each size WIDTHxDEPTH is the `ml45` preset's policy (96 px images in 12 px patches, chunks of 8, 16 word tokens)
with that width and depth (4 heads, as the preset). On a synthetic store (no simulator), the median wall time of a
training step as `gazereg train` runs it without gaze (explicit-softmax attention, fused AdamW, autocast in the
precision `--train.mixed_precision auto` resolves to here), sizes interleaved over rounds so a noisy CPU affects
all alike; with each size's parameter count and the hours `--pretrain-steps` steps would take at that rate.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import torch
from _timing import machine_info, machine_line, print_markdown
from bench_train import make_store

from gazereg.data.dataset import EpisodeDataset, StepBatchSampler
from gazereg.experiment.pretrain_config import ml45_policy
from gazereg.policies.vla import Tokenizer, VLAPolicy
from gazereg.training.config import PRESETS
from gazereg.training.setup import make_optimiser, resolve_precision

INSTRUCTION = "pick up the puck and place it at the goal"


def parse_size(text: str) -> tuple[int, int]:
    width, _, depth = text.partition("x")
    return int(width), int(depth)


def build(width: int, depth: int) -> tuple[VLAPolicy, torch.optim.Optimizer]:
    torch.manual_seed(0)
    base = ml45_policy()
    tok = Tokenizer.build([INSTRUCTION], max_len=base.max_text_len)
    data = {"cameras": ("corner2",), "camera_hw": ((96, 96),), "state_dim": 4, "action_dim": 4}
    cfg = replace(base, dim=width, depth=depth, vocab_size=tok.vocab_size, **data)
    policy = VLAPolicy(cfg, tok)
    return policy, make_optimiser(policy, TRAIN_CFG)[0]


TRAIN_CFG = resolve_precision(PRESETS["tuned"]())


def step(policy: VLAPolicy, opt: torch.optim.Optimizer, batch: dict, i: int) -> None:
    bf16 = TRAIN_CFG.mixed_precision == "bf16"
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
        loss, _ = policy(batch, generator=torch.Generator().manual_seed(i), shift=4)
    opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(policy.parameters(), 1.0)
    opt.step()


def markdown_table(result: dict, source: str) -> str:
    """A JSON this script wrote as a markdown table under a line naming the machine, the batch and `source`."""
    head = f"{machine_line(result['machine'])}; batch {result['batch']}; from `{source}`:"
    steps = result["pretrain_steps"]
    lines = [
        head,
        "",
        f"| width x depth | parameters (M) | tokens | ms per step | hours for {steps:,} steps |",
        "|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['size']} | {r['params_m']:.2f} | {r['tokens']} | {r['step_ms']:.0f} | {r['hours_for_pretrain_steps']:.2f} |"
        for r in result["sizes"]
    ]
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", default=["128x4", "192x4", "192x6", "256x6"])
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--steps", type=int, default=8, help="timed steps per size per round")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--pretrain-steps", type=int, default=30_000)
    ap.add_argument(
        "--markdown", type=Path, default=None, metavar="JSON", help="measure nothing: print a JSON's table"
    )
    args = ap.parse_args()
    if args.markdown is not None:
        return print_markdown(args.markdown, markdown_table, "bench_pretrain_size.py")
    sizes = [parse_size(s) for s in args.sizes]
    models = {s: build(*s) for s in sizes}
    first = next(iter(models.values()))[0]
    store = make_store(Path(tempfile.mkdtemp()) / "s")
    geometry = first.geometry("corner2")
    ds = EpisodeDataset(
        store, store.indices(), ["corner2"], first.config.chunk, first.tokenizer, geometry=geometry
    )
    sampler = StepBatchSampler(len(ds), args.batch, 0, args.steps)
    batches = [ds.__getitems__(sampler.batch_indices(i)) for i in range(args.steps)]
    for policy, opt in models.values():  # warm-up: allocator, optimizer state
        for i in range(2):
            step(policy, opt, batches[i], i)
    times: dict[tuple[int, int], list[float]] = {s: [] for s in sizes}
    for _ in range(args.rounds):
        for s, (policy, opt) in models.items():
            for i, b in enumerate(batches):
                t0 = time.perf_counter()
                step(policy, opt, b, i)
                times[s].append(time.perf_counter() - t0)
    rows = []
    for (width, depth), ts in times.items():
        policy = models[(width, depth)][0]
        ms = 1000 * statistics.median(ts)
        rows.append(
            {
                "size": f"{width}x{depth}",
                "width": width,
                "depth": depth,
                "heads": policy.config.heads,
                "tokens": policy.n_tokens,
                "params_m": round(sum(p.numel() for p in policy.parameters()) / 1e6, 3),
                "step_ms": round(ms, 1),
                "hours_for_pretrain_steps": round(ms * args.pretrain_steps / 3.6e6, 2),
            }
        )
    out = {
        "machine": machine_info(TRAIN_CFG.mixed_precision),
        "batch": args.batch,
        "pretrain_steps": args.pretrain_steps,
        "sizes": rows,
    }
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
