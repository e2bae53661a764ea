"""How many paired episodes a gaze-vs-baseline comparison needs: exact McNemar power from the discordant
pairs a previous run measured (`only A solved`, `only B solved` of `pairs` in a report's paired table).

    python scripts/power.py --a-only 85 --b-only 8 --pairs 300 [--alpha 0.05] [--power 0.8] [--show 20,40,60]

Prints the measured rates, the fewest pairs reaching the power, and the power at the --show sizes.
"""

from __future__ import annotations

import argparse

from gazereg.evaluation.stats import mcnemar_power, pairs_for_power


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--a-only", type=int, required=True, help="pairs only arm A solved")
    ap.add_argument("--b-only", type=int, required=True, help="pairs only arm B solved")
    ap.add_argument("--pairs", type=int, required=True, help="pairs compared")
    ap.add_argument("--alpha", type=float, default=0.05)
    ap.add_argument("--power", type=float, default=0.8)
    ap.add_argument("--show", default="20,30,40,50,60,80,100", help="comma-separated pair counts")
    args = ap.parse_args(argv)
    if not 0 <= args.a_only + args.b_only <= args.pairs or min(args.a_only, args.b_only) < 0:
        ap.error(f"need 0 <= a-only + b-only <= pairs, got {args.a_only} + {args.b_only} of {args.pairs}")
    a, b = args.a_only / args.pairs, args.b_only / args.pairs
    print(f"discordant rates: only A {a:.3f}, only B {b:.3f} ({args.a_only}/{args.b_only} of {args.pairs})")
    need = pairs_for_power(a, b, args.power, args.alpha)
    print(f"fewest pairs for power {args.power} at alpha {args.alpha}: {need}")
    for n in (int(x) for x in args.show.split(",") if x):
        print(f"  {n:4d} pairs: power {mcnemar_power(a, b, n, args.alpha):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
