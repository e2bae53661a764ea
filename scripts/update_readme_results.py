"""Put an experiment's results into the README (the block between its markers).

python scripts/update_readme_results.py runs/quick [--marker quick-results]
python scripts/update_readme_results.py runs/paper6k --against runs/paper --marker paper-budget
    (the second: run B = runs/paper6k compared with run A = runs/paper on the setups both evaluated)
"""

import argparse
from pathlib import Path

from gazereg.report import replace_block, update_readme
from gazereg.report.compare import compare_markdown, compare_runs

ROOT = Path(__file__).resolve().parents[1]

if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--marker", default="quick-results")
    ap.add_argument(
        "--against", type=Path, help="write the comparison of run_dir (B) with this run (A) instead"
    )
    args = ap.parse_args()
    if args.against:
        replace_block(
            ROOT / "README.md",
            args.marker,
            compare_markdown(compare_runs(args.against, args.run_dir), level=4),
        )
    else:
        update_readme(ROOT / "README.md", args.run_dir, ROOT / "docs" / "figures", args.marker)
    print(f"README.md block {args.marker!r} updated from {args.run_dir}")
