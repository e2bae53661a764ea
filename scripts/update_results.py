"""Write experiment results into the docs pages' generated blocks and the README's headline.

    python scripts/update_results.py runs/demo                                   # block demo-results
    python scripts/update_results.py runs/paper --marker paper-results           # and the README's headline
    python scripts/update_results.py runs/paper6k --against runs/paper --marker paper-budget
        (run B = runs/paper6k compared with run A = runs/paper on the setups both evaluated)
    python scripts/update_results.py --headline                                  # only the README's headline
    python scripts/update_results.py --file runs/paper-s0/horizon500/horizon.md --marker paper-s0-horizon
        (a markdown file a script wrote, e.g. scripts/horizon.py's, as the block)
    python scripts/update_results.py runs/demo --check       # exit 1 if the run's numbers disagree with the block
    python scripts/update_results.py docs/records/pretrain-ml45 --marker pretrain-ml45
        (a `gazereg pretrain` folder or its archive: its block, `FinishedPretraining.block`)

A block is the text between a `<!-- NAME:start -->` and a `<!-- NAME:end -->` line (each a line of its own) on
one of the pages docs/*.md; everything outside the marker lines is left as it is. The script finds the page
that holds a marker by reading every docs/*.md: exactly one page must hold it (none, or two, is an error that
names the marker and the pages, before anything is written), so a block moves to another page by moving its
lines, with no change here. The same lookup serves writing, `--check` and the headline.

A run's block is `gazereg.report.results_block` of its report.json, with the run's attention figure copied to
docs/figures/<marker>-attention.png (linked as figures/..., relative to the docs pages); a comparison's block
is `gazereg.report.compare.compare_markdown`; a pretraining's (a folder `gazereg.experiment.is_pretraining`
recognises, read by `read_pretraining`, live or archived) is `gazereg.report.pretrain.pretrain_block`, its
data line holding its numerics key and the pooled success count of its one arm ("pretrained") and condition
("clean"), so --check treats it as below. The README's headline block is the head of the paper-results block
(its run line and success table, `gazereg.report.headline_lines`), copied from whichever page holds it so that
the two never disagree.

--check: a run's numbers depend on the machine it trained on (`--train.mixed_precision auto` trains in bf16
where the CPU has avx512_bf16 or amx_bf16, in float32 elsewhere, and torch's kernels differ by ISA level and
vendor), so every block ends with a data line (`gazereg.report.blockdata`: the run's
`gazereg.runtime.hardware.NumericsKey` -- resolved precision, torch CPU capability, bf16 instruction sets,
CPU vendor, torch version, GPU -- its success counts and its attention columns), and the check reads that
line from the page and from the run's freshly rendered block:
- equal keys: exact; every line but the run line (date, machine, wall time) must be the same;
- different keys (or a key one side does not record, or runs that trained on machines whose keys differ:
  no one key): agreement; the same arms, conditions and episodes per cell, and for each arm x condition a
  two-sided Fisher exact test of the page's k/n against the run's k/n with p >= 0.01 / (number of cells)
  (Bonferroni: equal success rates fail some cell with chance <= 0.01);
  the attention columns are not tested (their largest differences are printed), nor the verdict lines;
- a block without a data line (rendered before blocks carried one) fails, saying to regenerate it.
It prints which comparison it made and why.

A run's block that lacks arms the page's block has (a pool that kept only the arm groups every seed has, say)
is refused unless --drop-arms is given.

Bad input (a marker on no page or on several, a run folder without report.json (`read_report`), a missing
--file, a run missing arms the block has) is one line on stderr, `update_results.py: error: ...`, exit status
2, before any file is written.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path
from typing import Any

from gazereg.experiment.compare import compare_runs
from gazereg.experiment.finished import read_report
from gazereg.experiment.finished_pretrain import is_pretraining, read_pretraining
from gazereg.report import results_block
from gazereg.report.blockdata import DATA_PREFIX, FAMILY_ALPHA, BlockData, agreement, alignment_differences
from gazereg.report.compare import compare_markdown
from gazereg.runtime.errors import UsageError
from gazereg.runtime.hardware import NumericsKey
from gazereg.runtime.io import atomic_write_text

ROOT = Path(__file__).resolve().parents[1]
DOCS = Path("docs")  # relative to the repository root, like the two below: its *.md pages hold the blocks
FIGURES = DOCS / "figures"
README = Path("README.md")
MAIN_JOB = "demo-results"  # the main job's block (make demo), the default --marker
HEADLINE_SOURCE = "paper-results"  # the docs block whose head is the README's headline
HEADLINE = "headline"  # the README's block
PROG = "update_results.py"


class MarkerError(ValueError):
    """A marker that no docs page holds, or several do, or a page whose marker lines are not one pair."""


def marker_lines(marker: str) -> tuple[str, str]:
    """The start and end lines (without their newline) of block `marker`."""
    return f"<!-- {marker}:start -->", f"<!-- {marker}:end -->"


def _marker_indices(lines: list[str], marker: str) -> tuple[list[int], list[int]]:
    """The indices of `lines` that are `marker`'s start line, and those that are its end line (a marker
    mentioned inside a line of prose is neither)."""
    start, end = marker_lines(marker)
    stripped = [line.strip() for line in lines]
    return [i for i, s in enumerate(stripped) if s == start], [i for i, s in enumerate(stripped) if s == end]


def find_page(root: Path, marker: str) -> Path:
    """The page of `root`/docs/*.md that holds block `marker` (a start or an end line of it); exactly one page
    must, else `MarkerError` naming the marker and the pages."""
    pages = [
        page
        for page in sorted((root / DOCS).glob("*.md"))
        if any(_marker_indices(page.read_text().splitlines(), marker))
    ]
    if len(pages) == 1:
        return pages[0]
    start, end = marker_lines(marker)
    if not pages:
        raise MarkerError(
            f"no page {DOCS.as_posix()}/*.md holds block {marker!r} (a {start} line and a {end} line): "
            "add the pair to the page the block belongs on"
        )
    names = ", ".join(page.relative_to(root).as_posix() for page in pages)
    raise MarkerError(f"block {marker!r} is on {len(pages)} pages ({names}): it must be on exactly one")


def _split(text: str, marker: str, where: Path) -> tuple[str, str, str]:
    """(text up to and with the block's start line, the block, text from its end line on)."""
    lines = text.splitlines(keepends=True)
    starts, ends = _marker_indices(lines, marker)
    start, end = marker_lines(marker)
    if len(starts) != 1 or len(ends) != 1 or ends[0] < starts[0]:
        raise MarkerError(
            f"{where} has no single {start} ... {end} block ({len(starts)} start and {len(ends)} end lines)"
        )
    s, e = starts[0], ends[0]
    return "".join(lines[: s + 1]), "".join(lines[s + 1 : e]), "".join(lines[e:])


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


def figure_of(marker: str) -> Path:
    """Where block `marker`'s attention figure lives, relative to the repository root."""
    return FIGURES / f"{marker}-attention.png"


def run_block(report: dict[str, Any], marker: str) -> str:
    """The results block of an experiment's (or a pool's) report, its attention figure linked relative to the
    docs pages (figures/<marker>-attention.png; `copy_figure` puts it there)."""
    return results_block(report, figure_of(marker).relative_to(DOCS).as_posix())


def copy_figure(root: Path, run_dir: Path, report: dict[str, Any], marker: str) -> None:
    """Copy the attention figure of `report` (the report of `run_dir`) to where its block links it
    (`figure_of`)."""
    (root / FIGURES).mkdir(parents=True, exist_ok=True)
    shutil.copyfile(run_dir / report["figures"]["attention"], root / figure_of(marker))


def produce_block(run_dir: Path, report: dict[str, Any] | None, marker: str) -> str:
    """The block of `run_dir`: a pretraining's (`report` None: `FinishedPretraining.block`; no figure) or an
    experiment's or a pool's (`run_block` of its report, as `read_report` read it)."""
    return read_pretraining(run_dir).block() if report is None else run_block(report, marker)


def lost_arms(written: str, produced: str) -> list[str]:
    """The arms the page's block counts successes for that the produced block does not (both read from their
    data lines; none when either block has no data line)."""
    page, run = BlockData.read(written), BlockData.read(produced)
    if page is None or run is None:
        return []
    return sorted(set(page.success) - set(run.success))


def block_differences(written: str, produced: str) -> list[str]:
    """The lines where a block on the page and a freshly rendered one differ, leaving out the run line (its
    first line: date, machine and wall time change from run to run; the numbers below it must not)."""
    a, b = written.splitlines()[1:], produced.splitlines()[1:]
    out = [f"page: {x!r} | run: {y!r}" for x, y in zip(a, b) if x != y]
    if len(a) != len(b):
        out.append(f"the page's block has {len(a) + 1} lines, the run's {len(b) + 1}")
    return out


def check(root: Path, run_dir: Path, report: dict[str, Any] | None, marker: str) -> int:
    """0 when the run's numbers are those of the docs block `marker` (exactly, for equal numerics keys) or
    agree with them (`blockdata.agreement`, for different keys), else 1; prints which comparison it made and
    its outcome. A block without a data line (made before blocks carried one) fails: it must be regenerated.
    `report`: the run's, as `produce_block` takes it."""
    docs_page = find_page(root, marker)
    written, produced = read_block(docs_page, marker), produce_block(run_dir, report, marker)
    where = f"{docs_page.relative_to(root).as_posix()} block {marker!r}"
    page, run = BlockData.read(written), BlockData.read(produced)
    if page is None:
        print(
            f"{where} predates the numerics key (it has no {DATA_PREFIX.strip()} line), so it cannot say which "
            f"machine and precision its numbers need: regenerate it with `python scripts/update_results.py "
            f"{run_dir}{'' if marker == MAIN_JOB else f' --marker {marker}'}` and commit it"
        )
        return 1
    assert run is not None  # results_block and pretrain_block always write the data line
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
    several = next(
        (side for side, d in (("page", page), ("run", run)) if d.numerics is None and d.machines), ""
    )
    if several:
        keys = (page if several == "page" else run).machines
        why = f"the {several} trained on several machines ({'; '.join(k.describe() for k in keys)})"
    elif page.numerics is None or run.numerics is None:
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


def update_headline(root: Path) -> Path:
    """Copy the head of the paper-results block (on whichever docs page holds it) into the README's headline
    block; returns that page."""
    source = find_page(root, HEADLINE_SOURCE)
    read_block(root / README, HEADLINE)  # the README must hold its block before anything is written
    replace_block(root / README, HEADLINE, headline_of(read_block(source, HEADLINE_SOURCE)))
    return source


def _target(root: Path, marker: str) -> Path:
    """The docs page holding block `marker`, its marker lines checked, and for the headline's source the
    README's headline block too: every `MarkerError` comes before anything is written."""
    page = find_page(root, marker)
    read_block(page, marker)
    if marker == HEADLINE_SOURCE:
        read_block(root / README, HEADLINE)
    return page


def _usage_error(message: str) -> int:
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return 2


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    ap.add_argument(
        "run_dir",
        type=Path,
        nargs="?",
        help="the experiment's output folder (its --out), a pretraining folder, or an archive of either",
    )
    ap.add_argument(
        "--marker",
        default=MAIN_JOB,
        help="the block to replace (on whichever docs/*.md page holds it)",
    )
    ap.add_argument(
        "--against", type=Path, help="write the comparison of run_dir (B) with this run (A) instead"
    )
    ap.add_argument(
        "--headline", action="store_true", help="only copy the README's headline from the paper-results block"
    )
    ap.add_argument("--file", type=Path, help="write this markdown file (a script's output) as the block")
    ap.add_argument("--root", type=Path, default=ROOT, help="the repository to update (default: this one)")
    ap.add_argument(
        "--drop-arms",
        action="store_true",
        help="write a run's block even where it lacks arms the page's block has (refused otherwise)",
    )
    ap.add_argument(
        "--check",
        action="store_true",
        help="change nothing; exit 1 if the run's block differs from the page's",
    )
    args = ap.parse_args(argv)
    if not (args.headline or args.file) and args.run_dir is None:
        return _usage_error("run_dir is needed unless --headline or --file is given")
    try:
        return _run(args)
    except (MarkerError, UsageError) as e:
        return _usage_error(str(e))


def _run(args: argparse.Namespace) -> int:
    root = args.root
    if args.headline:
        source = update_headline(root)
        print(
            f"README.md block {HEADLINE!r} updated from {source.relative_to(root).as_posix()} block {HEADLINE_SOURCE!r}"
        )
        return 0
    page = _target(root, args.marker)
    where = f"{page.relative_to(root).as_posix()} block {args.marker!r}"
    if args.file:
        if not args.file.is_file():
            return _usage_error(f"--file {args.file}: no such file")
        replace_block(page, args.marker, args.file.read_text().rstrip("\n") + "\n")
        print(f"{where} updated from {args.file}")
        return 0
    pretraining = is_pretraining(args.run_dir)
    if args.against and pretraining:
        return _usage_error(f"--against compares experiments; {args.run_dir} is a pretraining folder")
    reads_report = not pretraining and (args.check or not args.against)  # --check ignores --against
    report = read_report(args.run_dir) if reads_report else None  # UsageError when it has none
    if args.check:
        return check(root, args.run_dir, report, args.marker)
    if args.against:
        block = compare_markdown(compare_runs(args.against, args.run_dir), level=4)
    else:
        block = produce_block(args.run_dir, report, args.marker)
        lost = lost_arms(read_block(page, args.marker), block)
        if lost and not args.drop_arms:
            return _usage_error(
                f"{args.run_dir} lacks arm(s) {', '.join(lost)} that {where} has (a pool of fewer arms?); "
                "--drop-arms writes it anyway"
            )
        if report is not None:
            copy_figure(root, args.run_dir, report, args.marker)
    replace_block(page, args.marker, block)
    print(f"{where} updated from {args.run_dir}")
    if args.marker == HEADLINE_SOURCE:
        update_headline(root)
        print(f"README.md block {HEADLINE!r} updated from it")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
