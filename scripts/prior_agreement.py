"""How far each gaze prior of a store is from a reference prior, on the policy's patch grid: the question an
ablation's control raises ("is other-episode gaze really at the wrong places?").

    python scripts/prior_agreement.py runs/paper-abl-a/demos --reference visuomotor \
        --priors visuomotor-other-episode visuomotor-shuffled uniform --out runs/prior_agreement.md

Every frame where both priors are valid counts once: KL(reference || prior) in nats, CC and SIM of the two
patch distributions, and how many patches apart their peaks are (Chebyshev distance on the grid; 0: the same
patch). A markdown table goes to --out (written whole) and stdout.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

from gazereg import metrics
from gazereg.data.store import EpisodeStore
from gazereg.patches import PatchGeometry, patch_distribution
from gazereg.runtime.errors import UsageError, report_errors
from gazereg.runtime.io import atomic_write_text


def peak_distance(a: torch.Tensor, b: torch.Tensor, grid: tuple[int, int]) -> torch.Tensor:
    """(F,) Chebyshev distance in patches between the peaks of (F, n_patches) distributions on `grid`; NaN
    where either is flat (no peak: uniform gaze)."""
    w = grid[1]
    ia, ib = a.argmax(-1), b.argmax(-1)
    d = torch.maximum((ia // w - ib // w).abs(), (ia % w - ib % w).abs()).float()
    flat = ((a.amax(-1) - a.amin(-1)) < 1e-9) | ((b.amax(-1) - b.amin(-1)) < 1e-9)
    return torch.where(flat, torch.nan, d)


def agreement(store: EpisodeStore, reference: str, prior: str, geometry: PatchGeometry) -> dict[str, float]:
    """Frame means of KL, CC, SIM and the peak distance between `prior` and `reference` over the store."""
    parts: dict[str, list[torch.Tensor]] = {"kl": [], "cc": [], "sim": [], "peak": []}
    grid = geometry.grid_hw
    for index in store.indices():
        heat, valid = store.read_prior(reference, index)
        ref, ref_ok = patch_distribution(heat, geometry, valid)
        heat, valid = store.read_prior(prior, index)
        other, ok = patch_distribution(heat, geometry, valid)
        if ref.shape != other.shape:
            raise UsageError(
                f"episode {index}: {prior} has {other.shape[0]} frames, {reference} {ref.shape[0]}"
            )
        both = ref_ok & ok
        ref, other = ref[both], other[both]
        parts["kl"].append(metrics.kl(ref, other))
        parts["cc"].append(metrics.cc(ref, other))
        parts["sim"].append(metrics.sim(ref, other))
        parts["peak"].append(peak_distance(ref, other, grid))
    out = {k: float(torch.cat(v).mean()) for k, v in parts.items()}  # NaN peak: a flat prior has none
    peaks = torch.cat(parts["peak"])
    same = float("nan") if peaks.isnan().any() else float((peaks == 0).float().mean())
    return {**out, "same_peak": same, "frames": int(peaks.numel())}


def _num(x: float) -> str:
    return "n/a (flat)" if x != x else f"{x:.2f}"


def table(store: Path, reference: str, rows: dict[str, dict[str, float]], geometry: PatchGeometry) -> str:
    (h, w), px, size = geometry.grid_hw, geometry.patch_size, geometry.input_hw[0]
    lines = [
        f"## Gaze priors against `{reference}` on {store} ({h}x{w} patches of {px} px at {size} px)",
        "",
        "| prior | frames | KL (nats) | CC | SIM | peak distance (patches) | same peak patch |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        lines.append(
            f"| {name} | {r['frames']} | {r['kl']:.3f} | {r['cc']:.3f} | {r['sim']:.3f} | "
            f"{_num(r['peak'])} | {_num(r['same_peak'])} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("store", type=Path, help="an episode store with the priors (a run folder's demos/)")
    p.add_argument("--reference", default="visuomotor")
    p.add_argument("--priors", nargs="+", required=True)
    p.add_argument("--image", type=int, default=96, help="the policy's square input size, px")
    p.add_argument("--patch", type=int, default=12, help="the policy's patch size, px")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(sys.argv[1:] if argv is None else argv)
    if not (args.store / "store.json").exists():
        raise UsageError(f"{args.store} is not an episode store (no store.json)")
    started = time.perf_counter()
    store = EpisodeStore(args.store)
    geometry = PatchGeometry(input_hw=(args.image, args.image), patch_size=args.patch)
    rows = {name: agreement(store, args.reference, name, geometry) for name in args.priors}
    text = table(args.store, args.reference, rows, geometry)
    command = " ".join(["python scripts/prior_agreement.py", *(sys.argv[1:] if argv is None else argv)])
    text += f"\nCommand: `{command}`; wall time {time.perf_counter() - started:.0f} s.\n"
    atomic_write_text(args.out, text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(report_errors("prior_agreement", main, sys.argv[1:], verbose=False))
