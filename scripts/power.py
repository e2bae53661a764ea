"""How many paired episodes a gaze-vs-baseline comparison needs: exact McNemar power from the discordant
pairs a previous run measured (`only A solved`, `only B solved` of `pairs`), given as counts or read from the
run's own episodes.

    python scripts/power.py --a-only 85 --b-only 8 --pairs 300 [--alpha 0.05] [--power 0.8] [--show 20,40,60]
    python scripts/power.py --run docs/records/study10-s0 [--arm gaze] [--reference baseline] \
        [--tasks box-close-v3 door-unlock-v3] [--condition clean] --show 100

With --run (one or more finished experiments or their archives, read by `gazereg.experiment.read_run`), A is
--arm and B is --reference, paired by (training seed, task, setup seed) on the final checkpoints' episodes of
--condition, on --tasks only when given. Prints the measured rates, the fewest pairs reaching the power, and
the power at the --show sizes. Bad input: one line, exit 2.
"""

from __future__ import annotations

import argparse
import contextlib

from gazereg.evaluation.stats import mcnemar_power, pairs_for_power, pairs_for_power_normal
from gazereg.experiment import read_run
from gazereg.report.tables import paired_name, paired_tests
from gazereg.runtime.errors import UsageError


def measured_pairs(
    runs: list[str], arm: str, reference: str, condition: str, tasks: list[str] | None
) -> tuple[int, int, int]:
    """(pairs only `arm` solved, pairs only `reference` solved, pairs) in the finished runs `runs`."""
    finished = [read_run(path) for path in runs]
    known = {t for run in finished for t in run.tasks}
    if tasks and set(tasks) - known:
        raise UsageError(
            f"--tasks {sorted(set(tasks) - known)} are not tasks of {runs} (their tasks: {sorted(known)})"
        )
    records = [
        r
        for run in finished
        for r in run.episodes()
        if r["condition"] == condition and (not tasks or r["task"] in tasks)
    ]
    table = paired_tests(records, reference).get(paired_name(arm, reference, condition))
    if table is None:
        raise UsageError(f"{runs} have no episodes of {arm} paired with {reference} under {condition}")
    return table[f"{arm}_only"], table[f"{reference}_only"], table["pairs"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--a-only", type=int, help="pairs only arm A solved")
    ap.add_argument("--b-only", type=int, help="pairs only arm B solved")
    ap.add_argument("--pairs", type=int, help="pairs compared")
    ap.add_argument("--run", nargs="+", help="finished experiments whose paired episodes give the counts")
    ap.add_argument("--arm", default="gaze", help="arm A of --run")
    ap.add_argument("--reference", default="baseline", help="arm B of --run")
    ap.add_argument("--condition", default="clean", help="the condition of --run's episodes")
    ap.add_argument("--tasks", nargs="+", help="only these tasks of --run")
    ap.add_argument("--alpha", type=float, default=0.05)
    ap.add_argument("--power", type=float, default=0.8)
    ap.add_argument("--max-pairs", type=int, default=2000, help="the most pairs the exact search tries")
    ap.add_argument("--show", default="20,30,40,50,60,80,100", help="comma-separated pair counts")
    args = ap.parse_args(argv)
    counts = (args.a_only, args.b_only, args.pairs)
    if args.run:
        if any(c is not None for c in counts):
            ap.error("give --run or the counts (--a-only, --b-only, --pairs), not both")
        try:
            a_only, b_only, pairs = measured_pairs(
                args.run, args.arm, args.reference, args.condition, args.tasks
            )
        except UsageError as e:
            ap.error(str(e))
        what = f"{args.arm} vs {args.reference}, {args.condition}, in {' '.join(args.run)}"
        if args.tasks:
            what += f" on {' '.join(args.tasks)}"
        print(f"measured: {what}")
    elif None in counts:
        ap.error("give --a-only, --b-only and --pairs, or --run")
    else:
        a_only, b_only, pairs = counts
    if not 0 <= a_only + b_only <= pairs or min(a_only, b_only) < 0:
        ap.error(f"need 0 <= a-only + b-only <= pairs, got {a_only} + {b_only} of {pairs}")
    if a_only + b_only == 0:
        ap.error(f"no discordant pairs among {pairs}: the rates give no power to compute")
    a, b = a_only / pairs, b_only / pairs
    print(f"discordant rates: only A {a:.3f}, only B {b:.3f} ({a_only}/{b_only} of {pairs})")
    approx = pairs_for_power_normal(a, b, args.power, args.alpha)
    need: int | str = f"more than {args.max_pairs} (about {approx:.0f} by the normal approximation)"
    if approx <= args.max_pairs / 2:  # the exact scan is quick only where few pairs are needed
        with contextlib.suppress(ValueError):  # past --max-pairs: the "more than" line stands
            need = pairs_for_power(a, b, args.power, args.alpha, limit=args.max_pairs)
    print(f"fewest pairs for power {args.power} at alpha {args.alpha}: {need}")
    for n in (int(x) for x in args.show.split(",") if x):
        print(f"  {n:4d} pairs: power {mcnemar_power(a, b, n, args.alpha):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
