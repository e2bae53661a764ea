"""Write experiment results into docs/results.md (the block between a marker pair) and the README's headline.

    python scripts/update_results.py runs/quick                                  # block quick-results
    python scripts/update_results.py runs/paper --marker paper-results           # and the README's headline
    python scripts/update_results.py runs/paper6k --against runs/paper --marker paper-budget
        (run B = runs/paper6k compared with run A = runs/paper on the setups both evaluated)
    python scripts/update_results.py --headline                                  # only the README's headline
    python scripts/update_results.py --file runs/paper-s0/horizon500/horizon.md --marker paper-horizon
        (a markdown file a script wrote, e.g. scripts/horizon.py's, as the block)
    python scripts/update_results.py runs/quick --check      # exit 1 if the run's numbers disagree with the block

A run's block is `gazereg.report.results_block` of its report.json, with the run's attention figure copied to
docs/figures/<marker>-attention.png; a comparison's block is `gazereg.report.compare.compare_markdown`. The
README's headline block is the head of docs/results.md's paper-results block (its run line and success table,
`gazereg.report.headline_lines`), copied from there so that the two pages never disagree. Blocks are
delimited by `<!-- NAME:start -->` and `<!-- NAME:end -->` lines; everything outside them is left as it is.

--check: a run's numbers depend on the machine it trained on (`--train.mixed_precision auto` trains in bf16
where the CPU has avx512_bf16 or amx_bf16, in float32 elsewhere, and torch's kernels differ by ISA level and
vendor), so every block ends with a data line (`gazereg.report.blockdata`: the run's
`gazereg.runtime.hardware.NumericsKey` -- resolved precision, torch CPU capability, bf16 instruction sets,
CPU vendor, torch version, GPU -- its success counts and its attention columns), and the check reads that
line from the page and from the run's freshly rendered block:
- equal keys: exact; every line but the run line (date, machine, wall time) must be the same;
- different keys (or a key one side does not record): agreement; the same arms, conditions and episodes per
  cell, and for each arm x condition a two-sided Fisher exact test of the page's k/n against the run's k/n
  with p >= 0.01 / (number of cells) (Bonferroni: equal success rates fail some cell with chance <= 0.01);
  the attention columns are not tested (their largest differences are printed), nor the verdict lines;
- a block without a data line (rendered before blocks carried one) fails, saying to regenerate it.
It prints which comparison it made and why.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from gazereg.report import results_block
from gazereg.report.blockdata import DATA_PREFIX, FAMILY_ALPHA, BlockData, agreement, alignment_differences
from gazereg.report.compare import compare_markdown, compare_runs
from gazereg.runtime.hardware import NumericsKey
from gazereg.runtime.io import atomic_write_text

ROOT = Path(__file__).resolve().parents[1]
RESULTS_PAGE = Path("docs") / "results.md"  # relative to the repository root, like the two below
FIGURES = Path("docs") / "figures"
README = Path("README.md")
HEADLINE_SOURCE = "paper-results"  # the docs/results.md block whose head is the README's headline
HEADLINE = "headline"  # the README's block


def _split(text: str, marker: str, where: Path) -> tuple[str, str, str]:
    """(text before the block's start line, the block, text from its end line on)."""
    start, end = f"<!-- {marker}:start -->", f"<!-- {marker}:end -->"
    if start not in text or end not in text:
        raise ValueError(f"{where} has no {start} ... {end} block")
    head, rest = text.split(start, 1)
    block, tail = rest.split(end, 1)
    return f"{head}{start}\n", block.removeprefix("\n"), f"{end}{tail}"


def read_block(page: Path, marker: str) -> str:
    """The text between `page`'s `<!-- {marker}:start -->` and `<!-- {marker}:end -->` lines."""
    return _split(page.read_text(), marker, page)[1]


def replace_block(page: Path, marker: str, block: str) -> None:
    """Replace the text between `page`'s marker lines with `block` (which ends with a newline); atomic."""
    head, _, tail = _split(page.read_text(), marker, page)
    atomic_write_text(page, f"{head}{block}{tail}")


def headline_of(block: str) -> str:
    """The head of a results block: its lines up to the end of its first table (the run line and the success
    table that `headline_lines` renders), then one blank line, so that the table ends before the end marker."""
    lines = block.splitlines()
    first = next((i for i, line in enumerate(lines) if line.startswith("|")), None)
    if first is None:
        raise ValueError("the results block has no table")
    stop = next((i for i in range(first, len(lines)) if not lines[i].startswith("|")), len(lines))
    return "\n".join(lines[:stop]) + "\n\n"


def run_block(root: Path, run_dir: Path, marker: str, copy_figure: bool = True) -> str:
    """The results block of the experiment in `run_dir`, its attention figure copied beside docs/results.md."""
    report = json.loads((run_dir / "report.json").read_text())
    figure = FIGURES / f"{marker}-attention.png"
    if copy_figure:
        (root / FIGURES).mkdir(parents=True, exist_ok=True)
        shutil.copyfile(run_dir / report["figures"]["attention"], root / figure)
    return results_block(report, figure.relative_to(RESULTS_PAGE.parent).as_posix())


def block_differences(written: str, produced: str) -> list[str]:
    """The lines where a block on the page and a freshly rendered one differ, leaving out the run line (its
    first line: date, machine and wall time change from run to run; the numbers below it must not)."""
    a, b = written.splitlines()[1:], produced.splitlines()[1:]
    out = [f"page: {x!r} | run: {y!r}" for x, y in zip(a, b) if x != y]
    if len(a) != len(b):
        out.append(f"the page's block has {len(a) + 1} lines, the run's {len(b) + 1}")
    return out


def check(root: Path, run_dir: Path, marker: str) -> int:
    """0 when the run's numbers are those of docs/results.md's block (exactly, for equal numerics keys) or
    agree with them (`blockdata.agreement`, for different keys), else 1; prints which comparison it made and
    its outcome. A block without a data line (made before blocks carried one) fails: it must be regenerated."""
    written, produced = read_block(root / RESULTS_PAGE, marker), run_block(root, run_dir, marker, False)
    where = f"{RESULTS_PAGE} block {marker!r}"
    page, run = BlockData.read(written), BlockData.read(produced)
    if page is None:
        print(
            f"{where} predates the numerics key (it has no {DATA_PREFIX.strip()} line), so it cannot say which "
            f"machine and precision its numbers need: regenerate it with `python scripts/update_results.py "
            f"{run_dir}{'' if marker == 'quick-results' else f' --marker {marker}'}` and commit it"
        )
        return 1
    assert run is not None  # results_block always writes the data line
    if page.numerics is not None and page.numerics == run.numerics:
        return _check_exact(written, produced, run_dir, where, page.numerics)
    return _check_agreement(page, run, run_dir, where)


def _check_exact(written: str, produced: str, run_dir: Path, where: str, key: NumericsKey) -> int:
    """The same numerics key: every line of the block but the run line must be equal."""
    diffs = block_differences(written, produced)
    if diffs:
        print(
            f"{run_dir} does not reproduce {where} exactly although both have the numerics key "
            f"({key.describe()}): {len(diffs)} lines differ; first: {diffs[0]}; regenerate the block at "
            "the commit that changed the numbers"
        )
        return 1
    print(f"{run_dir} reproduces {where} exactly (same numerics key: {key.describe()})")
    return 0


def _check_agreement(page: BlockData, run: BlockData, run_dir: Path, where: str) -> int:
    """Different (or unrecorded) numerics keys: the success counts must agree by `blockdata.agreement`."""
    if page.numerics is None or run.numerics is None:
        why = f"the {'page' if page.numerics is None else 'run'} records no training precision"
    else:
        why = f"numerics differ: {'; '.join(page.numerics.differences(run.numerics))} (page vs run)"
    result = agreement(page, run)
    print(
        f"{run_dir} vs {where}: {why}, so not an exact comparison but a test of agreement: same arms, "
        f"conditions and episodes, and every arm x condition success count within a two-sided Fisher exact "
        f"test of the page's at p >= {FAMILY_ALPHA}/{len(result.cells)} = {result.threshold:.3g} (Bonferroni)"
    )
    for c in result.cells:
        print(
            f"  {c.arm} x {c.condition}: page {c.page[0]}/{c.page[1]}, run {c.run[0]}/{c.run[1]}, p = {c.p:.3g}"
        )
    spread = alignment_differences(page, run)
    if spread:
        largest = ", ".join(f"{m} {d:.3f}" for m, d in spread.items())
        print(
            f"  attention columns not tested (one run per machine gives no spread); largest |differences|: {largest}"
        )
    if not result.agrees:
        print(f"{run_dir} does not agree with {where}: {'; '.join(result.problems)}")
        return 1
    print(f"{run_dir} agrees with {where} (not identical: different numerics)")
    return 0


def update_headline(root: Path) -> None:
    """Copy the head of docs/results.md's paper-results block into the README's headline block."""
    replace_block(root / README, HEADLINE, headline_of(read_block(root / RESULTS_PAGE, HEADLINE_SOURCE)))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path, nargs="?", help="the experiment's output folder (its --out)")
    ap.add_argument("--marker", default="quick-results", help="the docs/results.md block to replace")
    ap.add_argument(
        "--against", type=Path, help="write the comparison of run_dir (B) with this run (A) instead"
    )
    ap.add_argument(
        "--headline", action="store_true", help="only copy the README's headline from docs/results.md"
    )
    ap.add_argument("--file", type=Path, help="write this markdown file (a script's output) as the block")
    ap.add_argument("--root", type=Path, default=ROOT, help="the repository to update (default: this one)")
    ap.add_argument(
        "--check",
        action="store_true",
        help="change nothing; exit 1 if the run's block differs from the page's",
    )
    args = ap.parse_args(argv)
    if args.headline:
        update_headline(args.root)
        print(f"README.md block {HEADLINE!r} updated from {RESULTS_PAGE} block {HEADLINE_SOURCE!r}")
        return 0
    if args.file:
        replace_block(args.root / RESULTS_PAGE, args.marker, args.file.read_text().rstrip("\n") + "\n")
        print(f"{RESULTS_PAGE} block {args.marker!r} updated from {args.file}")
        return 0
    if args.run_dir is None:
        ap.error("run_dir is needed unless --headline or --file is given")
    if args.check:
        return check(args.root, args.run_dir, args.marker)
    if args.against:
        block = compare_markdown(compare_runs(args.against, args.run_dir), level=4)
    else:
        block = run_block(args.root, args.run_dir, args.marker)
    replace_block(args.root / RESULTS_PAGE, args.marker, block)
    print(f"{RESULTS_PAGE} block {args.marker!r} updated from {args.run_dir}")
    if args.marker == HEADLINE_SOURCE:
        update_headline(args.root)
        print(f"README.md block {HEADLINE!r} updated from it")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
