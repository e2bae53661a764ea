"""The benchmark runs in the paper's table layout (`gazereg.report.paper_table`): one row per LIBERO suite and
Gym-Aloha task, our arms beside the paper's second-hand figures.

    python scripts/paper_table.py --run libero_spatial=docs/records/libero-spatial-s0,docs/records/libero-spatial-s0-glc \
        --run aloha=docs/records/aloha --out runs/paper-table.md
    python scripts/update_results.py --file runs/paper-table.md --marker paper-table

Each --run is ROW=FOLDER[,FOLDER...]: a row key (libero_spatial, libero_object, libero_goal, libero_10,
aloha_transfer_cube, aloha_insertion, or aloha for both Aloha rows of one run) and a finished experiment folder,
its archive or a pooled report; several folders (a benchmark's sittings) are read as one experiment
(`gazereg.experiment.pooled`). Rows without a run show the paper's figures only. Bad input (an unknown row, a
folder that is no finished run, a run of the wrong simulator, folders of different experiments or one run in
two of them) is one line on stderr and exit 2, before anything is written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gazereg.experiment.pooled import pooled_runs, read_results
from gazereg.report.paper_table import paper_table
from gazereg.runtime.errors import UsageError
from gazereg.runtime.io import atomic_write_text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--run", action="append", default=[], metavar="ROW=FOLDER[,FOLDER...]", help="a row and its run(s)"
    )
    ap.add_argument("--out", type=Path, help="write the markdown here (default: standard output)")
    args = ap.parse_args(argv)
    try:
        runs = {}
        for spec in args.run:
            key, sep, folder = spec.partition("=")
            if not sep or not key or not folder:
                raise UsageError(f"--run {spec!r}: expected ROW=FOLDER")
            if key in runs:
                raise UsageError(f"paper-table row {key!r} given twice")
            parts = [read_results(Path(f)) for f in folder.split(",")]
            runs[key] = parts[0] if len(parts) == 1 else pooled_runs(parts)
        text = paper_table(runs)
    except UsageError as e:
        print(f"{Path(__file__).name}: error: {e}", file=sys.stderr)
        return 2
    if args.out is None:
        print(text, end="")
    else:
        atomic_write_text(args.out, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
