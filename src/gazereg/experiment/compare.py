"""`gazereg compare A B`: two finished experiments (run folders or their archives, `gazereg archive`) side by
side, paired by arm, training seed, task, condition and setup seed (`gazereg.report.compare` does the
statistics and writes the table).

    gazereg compare runs/paper runs/paper6k [--out runs/paper6k/compare.md]
    gazereg compare docs/records/paper-abl-b runs/paper-abl-b-longer
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, NoReturn

from gazereg.experiment.config import ExperimentConfig
from gazereg.experiment.finished import read_run
from gazereg.experiment.records import as_trained, with_added_keys
from gazereg.report.compare import compare_markdown, comparison
from gazereg.runtime.config import to_dict
from gazereg.runtime.errors import UsageError
from gazereg.runtime.io import atomic_write_json, atomic_write_text


def compare_runs(run_a: str | Path, run_b: str | Path) -> dict[str, Any]:
    """The comparison of run B against run A (`gazereg.report.compare.comparison`), each read with
    `read_run`. UsageError, one line, for a folder that is not a finished experiment or its archive, and for
    two runs that share no evaluated episode. A key one run's saved config has and the other's lacks (added
    to the configuration after the older run was made) takes its default in the older one, the behaviour it
    had then (`with_added_keys`), and a precision saved as "auto" is the one its runs recorded training in
    (`records.as_trained`), so "What differs" names only the settings that really differ."""
    a, b = read_run(run_a), read_run(run_b)
    saved_a, saved_b = as_trained(a.config, run_a), as_trained(b.config, run_b)
    default = to_dict(ExperimentConfig())
    try:
        return comparison(
            (str(run_a), str(run_b)),
            (with_added_keys(saved_a, default, saved_b), with_added_keys(saved_b, default, saved_a)),
            (a.episodes(), b.episodes()),
            (a.report, b.report),
        )
    except ValueError as e:  # nothing to pair: a usage error, in one line
        raise UsageError(f"{run_a} and {run_b}: {e}") from None


class _Parser(argparse.ArgumentParser):
    """argparse whose usage errors are `UsageError`s: `gazereg` prints them as one line and exits 2."""

    def error(self, message: str) -> NoReturn:
        raise UsageError(f"{message} (gazereg compare --help)")


def main(argv: list[str] | None = None) -> int:
    ap = _Parser(
        prog="gazereg compare",
        description="Compare two experiment runs evaluated on the same setups (paired by training seed, task, "
        "condition and setup seed). Each is a finished run folder or its archive (`gazereg archive`).",
    )
    ap.add_argument("run_a", type=Path, help="the reference run directory (A)")
    ap.add_argument("run_b", type=Path, help="the changed run directory (B)")
    ap.add_argument("--out", type=Path, help="write the markdown here (and the JSON beside it, .json)")
    args = ap.parse_args(argv)
    result = compare_runs(args.run_a, args.run_b)
    text = compare_markdown(result)
    if args.out:
        atomic_write_text(args.out, text)
        atomic_write_json(args.out.with_suffix(".json"), result)
    print(text, end="")
    return 0
