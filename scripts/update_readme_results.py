"""Put an experiment's results into the README (the block between its quick-results markers).

python scripts/update_readme_results.py runs/quick [--marker quick-results]
"""

import argparse
from pathlib import Path

from gazevla.report import update_readme

ROOT = Path(__file__).resolve().parents[1]

if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--marker", default="quick-results")
    args = ap.parse_args()
    update_readme(ROOT / "README.md", args.run_dir, ROOT / "docs" / "figures", args.marker)
    print(f"README.md updated from {args.run_dir / 'report.json'}")
