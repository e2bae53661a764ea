"""Rewrite the golden renderings from smoke_report.json with the code as it is now, after a deliberate change to
what report.md or a results block shows (review the diff before committing it):

    .venv/bin/python tests/report_golden/regenerate.py
"""

import json
from pathlib import Path

from gazereg.report import markdown, results_block

GOLDEN = Path(__file__).parent


def main() -> None:
    report = json.loads((GOLDEN / "smoke_report.json").read_text())
    (GOLDEN / "smoke_report.md").write_text(markdown(report))
    report["train"]["seeds"] = [0, 1]  # as tests/test_markdown.py renders the several-seed block
    (GOLDEN / "smoke_block_two_seeds.md").write_text(results_block(report, "figures/smoke-attention.png"))


if __name__ == "__main__":
    main()
