"""scripts/update_results.py: a results block goes onto the one docs/*.md page that holds its marker (none or
two is refused, naming the marker, before anything is written; issue 34), the README's headline is the head of
the paper-results block wherever it lives, nothing outside the markers changes, and --check compares a run with
a block exactly when their numerics keys are equal, by a stated test of agreement when they differ, and
refuses a block without its data line (issue 33). The repository's own pages: every marker on exactly one page,
every local link resolves, the findings page's numbers are quoted from blocks."""

import json
import re
import shutil
from pathlib import Path

import pytest

from gazereg.evaluation.stats import fisher_exact, wilson
from gazereg.report import headline_lines, results_block
from gazereg.report.blockdata import BlockData, agreement
from gazereg.report.markdown import BLOCK_ALIGNMENT_KEYS
from gazereg.runtime.hardware import NumericsKey

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = Path(__file__).parent / "report_golden"


MAIN_JOB = "# Main job\n<!-- demo-results:start -->\nold quick\n<!-- demo-results:end -->\nmiddle\n"
PAPER = "# Paper\nThe `<!-- demo-results:start -->` line is prose here.\n<!-- paper-results:start -->\nold paper\n<!-- paper-results:end -->\nend\n"
INDEX = "# Findings\n[main job](main-job.md)\n"


@pytest.fixture
def repo(tmp_path):
    """A repository with a README headline block and three docs pages: the quick block on one, the paper block
    on another (which mentions the quick marker inside a line of prose), none on the third."""
    (tmp_path / "docs").mkdir()
    (tmp_path / "README.md").write_text("# x\n<!-- headline:start -->\nold\n<!-- headline:end -->\nend\n")
    (tmp_path / "docs" / "main-job.md").write_text(MAIN_JOB)
    (tmp_path / "docs" / "paper.md").write_text(PAPER)
    (tmp_path / "docs" / "README.md").write_text(INDEX)
    return tmp_path


@pytest.fixture
def run(tmp_path):
    run = tmp_path / "run"
    report = json.loads((GOLDEN / "smoke_report.json").read_text())
    (run / "figures").mkdir(parents=True)
    (run / report["figures"]["attention"]).write_bytes(b"png")
    (run / "report.json").write_text(json.dumps(report))
    return run


def test_a_run_block_goes_onto_the_page_that_holds_its_marker_with_its_figure(script, repo, run):
    assert script.main([str(run), "--root", str(repo)]) == 0
    page = (repo / "docs" / "main-job.md").read_text()
    report = json.loads((run / "report.json").read_text())
    block = results_block(report, "figures/demo-results-attention.png")
    assert page == "# Main job\n<!-- demo-results:start -->\n" + block + "<!-- demo-results:end -->\nmiddle\n"
    assert (repo / "docs" / "paper.md").read_text() == PAPER  # the marker inside prose is not a block
    assert (repo / "docs" / "README.md").read_text() == INDEX
    assert (repo / "docs" / "figures" / "demo-results-attention.png").read_bytes() == b"png"
    assert "old" in (repo / "README.md").read_text()  # only paper-results feeds the headline


def test_the_paper_block_refreshes_the_readme_headline(script, repo, run):
    script.main([str(run), "--marker", "paper-results", "--root", str(repo)])
    report = json.loads((run / "report.json").read_text())
    readme = (repo / "README.md").read_text()
    head = "\n".join(headline_lines(report))
    assert readme == f"# x\n<!-- headline:start -->\n{head}\n\n<!-- headline:end -->\nend\n"
    assert "![attention](figures/paper-results-attention.png)" in (repo / "docs" / "paper.md").read_text()
    assert (repo / "docs" / "main-job.md").read_text() == MAIN_JOB


def test_headline_only_copies_from_the_page_holding_the_paper_block(script, repo, run):
    page = repo / "docs" / "paper.md"
    block = results_block(json.loads((run / "report.json").read_text()), "figures/f.png")
    script.replace_block(page, "paper-results", block)
    assert script.main(["--headline", "--root", str(repo)]) == 0
    assert script.read_block(repo / "README.md", "headline") == script.headline_of(block)
    assert script.headline_of(block).startswith("Latest `smoke` run")


def docs_bytes(repo):
    return {p.relative_to(repo).as_posix(): p.read_bytes() for p in sorted(repo.rglob("*")) if p.is_file()}


def test_a_marker_no_page_holds_is_refused_in_one_line_naming_it(script, repo, run, capsys):
    before = docs_bytes(repo)
    capsys.readouterr()
    for argv in (
        [str(run), "--marker", "paper-budget"],
        [str(run), "--marker", "paper-budget", "--check"],
        ["--file", str(run / "report.json"), "--marker", "paper-budget"],
    ):
        assert script.main([*argv, "--root", str(repo)]) == 2
        err = capsys.readouterr().err
        assert err == (
            "update_results.py: error: no page docs/*.md holds block 'paper-budget' (a <!-- paper-budget:start "
            "--> line and a <!-- paper-budget:end --> line): add the pair to the page the block belongs on\n"
        )
    assert docs_bytes(repo) == before  # not even the figure was copied
    assert script.main(["--root", str(repo)]) == 2  # no run and no --headline
    assert "run_dir is needed" in capsys.readouterr().err


def test_a_marker_on_two_pages_is_refused_naming_the_marker_and_both_pages(script, repo, run, capsys):
    (repo / "docs" / "copy.md").write_text(PAPER)  # the paper block on a second page
    before = docs_bytes(repo)
    capsys.readouterr()
    expected = (
        "update_results.py: error: block 'paper-results' is on 2 pages (docs/copy.md, docs/paper.md): "
        "it must be on exactly one\n"
    )
    for argv in (
        [str(run), "--marker", "paper-results"],
        ["--headline"],
        [str(run), "--marker", "paper-results", "--check"],
    ):
        assert script.main([*argv, "--root", str(repo)]) == 2
        assert capsys.readouterr().err == expected
    assert docs_bytes(repo) == before
    with pytest.raises(script.MarkerError, match="'paper-results' is on 2 pages"):
        script.find_page(repo, "paper-results")


def test_a_page_with_a_start_line_and_no_end_line_is_refused(script, repo, run, capsys):
    (repo / "docs" / "main-job.md").write_text("# Main job\n<!-- demo-results:start -->\nold quick\n")
    before = docs_bytes(repo)
    capsys.readouterr()
    assert script.main([str(run), "--root", str(repo)]) == 2
    assert (
        "main-job.md has no single <!-- demo-results:start --> ... <!-- demo-results:end --> block (1 start and 0 end"
        in (capsys.readouterr().err)
    )
    assert docs_bytes(repo) == before


def test_a_paper_block_is_not_written_when_the_readme_has_no_headline_block(script, repo, run, capsys):
    (repo / "README.md").write_text("# x\n")
    before = docs_bytes(repo)
    assert script.main([str(run), "--marker", "paper-results", "--root", str(repo)]) == 2
    assert "README.md has no single <!-- headline:start -->" in capsys.readouterr().err
    assert docs_bytes(repo) == before


def test_a_run_folder_without_a_report_is_refused_in_one_line(script, repo, tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert script.main([str(empty), "--root", str(repo)]) == 2
    assert capsys.readouterr().err == (
        f"update_results.py: error: {empty} has no report.json (not a finished experiment or pooled report folder)\n"
    )


def test_the_repositorys_readme_headline_is_the_head_of_its_paper_block(script, tmp_path):
    """The README's headline block is what the script makes of the paper-results block, not typed text."""
    readme_headline = script.read_block(ROOT / "README.md", "headline")
    paper = script.read_block(script.find_page(ROOT, "paper-results"), "paper-results")
    assert readme_headline == script.headline_of(paper)
    shutil.copytree(ROOT / "docs", tmp_path / "docs", ignore=shutil.ignore_patterns("figures"))
    shutil.copy(ROOT / "README.md", tmp_path / "README.md")
    script.main(["--headline", "--root", str(tmp_path)])
    assert (tmp_path / "README.md").read_text() == (ROOT / "README.md").read_text()


def quick_run(tmp_path, name, counts, key):
    """A run folder whose report.json is the golden one made a quick run: arms baseline and gaze, clean only,
    success `counts` {arm: (successes, n)}, trained with numerics `key` (None: a report that records none)."""
    report = json.loads((GOLDEN / "smoke_report.json").read_text())
    report["success"] = {
        arm: {
            "clean": {
                **report["success"][arm]["clean"],
                "successes": k,
                "n": n,
                "rate": k / n,
                "ci95": list(wilson(k, n)),
            }
        }
        for arm, (k, n) in counts.items()
    }
    report["alignment"] = {arm: report["alignment"][arm] for arm in counts}
    if key is not None:
        report["machine"].update(
            cpu_model="a test CPU",
            cpu_capability=key.cpu_capability,
            bf16_isa=list(key.bf16_isa),
            precision=key.precision,
            run_precisions={f"{arm}@s0": key.precision for arm in counts},
            numerics=key.to_dict(),
        )
    run = tmp_path / name
    (run / "figures").mkdir(parents=True)
    (run / report["figures"]["attention"]).write_bytes(b"png")
    (run / "report.json").write_text(json.dumps(report))
    return run


BF16_AMD = NumericsKey("bf16", "AVX512", ("avx512_bf16",), "AuthenticAMD", "2.13.0+cpu")
FP32_AVX2 = NumericsKey("no", "AVX2", (), "AuthenticAMD", "2.13.0+cpu")
DOCS = {"baseline": (28, 50), "gaze": (32, 50)}  # the quick block's counts before issue 33


def test_check_is_exact_when_the_numerics_keys_are_equal(script, repo, tmp_path, capsys):
    page_run = quick_run(tmp_path, "page", DOCS, BF16_AMD)
    assert script.main([str(page_run), "--root", str(repo)]) == 0
    capsys.readouterr()
    assert (
        script.main([str(quick_run(tmp_path, "same", DOCS, BF16_AMD)), "--root", str(repo), "--check"]) == 0
    )
    assert "reproduces docs/main-job.md block 'demo-results' exactly (same numerics key: bf16 mixed" in (
        capsys.readouterr().out
    )
    page = repo / "docs" / "main-job.md"
    text = page.read_text()
    start = text.index("<!-- demo-results:start -->\n") + len("<!-- demo-results:start -->\n")
    page.write_text(text[:start] + "Latest run: another date and wall time" + text[text.index("\n", start) :])
    assert script.main([str(page_run), "--root", str(repo), "--check"]) == 0  # the run line may differ
    # one success more: chance explains it, but equal keys must give equal numbers
    closer = quick_run(tmp_path, "closer", {"baseline": (29, 50), "gaze": (32, 50)}, BF16_AMD)
    capsys.readouterr()
    assert script.main([str(closer), "--root", str(repo), "--check"]) == 1
    out = capsys.readouterr().out
    assert "does not reproduce docs/main-job.md block 'demo-results' exactly although both have" in out
    assert "29/50" in out
    page.write_text(text.replace("| baseline | 28/50", "| baseline | 27/50", 1))  # a table typed by hand
    assert script.main([str(page_run), "--root", str(repo), "--check"]) == 1


def test_a_run_with_fewer_arms_than_the_block_is_refused_unless_dropping_is_asked(
    script, repo, tmp_path, capsys
):
    three = {**DOCS, "perturbed": (30, 50)}
    assert script.main([str(quick_run(tmp_path, "three", three, FP32_AVX2)), "--root", str(repo)]) == 0
    two = quick_run(tmp_path, "two", DOCS, FP32_AVX2)
    before = docs_bytes(repo)
    capsys.readouterr()
    assert script.main([str(two), "--root", str(repo)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "lacks arm(s) perturbed" in err and "--drop-arms" in err
    assert docs_bytes(repo) == before  # nothing written, the figure neither
    assert script.main([str(two), "--root", str(repo), "--drop-arms"]) == 0
    assert "| perturbed |" not in (repo / "docs" / "main-job.md").read_text()
    assert (
        script.main(
            [str(quick_run(tmp_path, "four", {**three, "glc": (31, 50)}, FP32_AVX2)), "--root", str(repo)]
        )
        == 0
    )


def test_check_tests_agreement_when_the_numerics_keys_differ(script, repo, tmp_path, capsys):
    """Issue 33: float32 on an AVX2 CPU got 17/50 and 26/50 against the bf16 block's 28/50 and 32/50."""
    script.main([str(quick_run(tmp_path, "page", DOCS, BF16_AMD)), "--root", str(repo)])
    capsys.readouterr()
    avx2 = quick_run(tmp_path, "avx2", {"baseline": (17, 50), "gaze": (26, 50)}, FP32_AVX2)
    assert script.main([str(avx2), "--root", str(repo), "--check"]) == 0
    out = capsys.readouterr().out
    assert "numerics differ: precision: bf16 vs no; cpu_capability: AVX512 vs AVX2; bf16_isa: " in out
    assert "not an exact comparison but a test of agreement" in out and "p >= 0.01/2 = 0.005" in out
    assert f"baseline x clean: page 28/50, run 17/50, p = {fisher_exact(28, 50, 17, 50):.3g}" in out
    assert "attention columns not tested" in out
    assert "agrees with docs/main-job.md block 'demo-results' (not identical: different numerics)" in out


def test_check_fails_counts_that_chance_does_not_explain_naming_the_arm(script, repo, tmp_path, capsys):
    script.main(
        [
            str(quick_run(tmp_path, "page", {"baseline": (40, 50), "gaze": (32, 50)}, BF16_AMD)),
            "--root",
            str(repo),
        ]
    )
    capsys.readouterr()
    avx2 = quick_run(tmp_path, "avx2", {"baseline": (17, 50), "gaze": (26, 50)}, FP32_AVX2)
    assert script.main([str(avx2), "--root", str(repo), "--check"]) == 1
    last = capsys.readouterr().out.splitlines()[-1]
    p = fisher_exact(40, 50, 17, 50)
    assert p < 0.005
    assert last == (
        f"{avx2} does not agree with docs/main-job.md block 'demo-results': baseline x clean: page 40/50, "
        f"run 17/50, Fisher exact p = {p:.3g} < 0.005"
    )


def test_a_run_without_a_key_is_tested_for_agreement_saying_so(script, repo, tmp_path, capsys):
    script.main([str(quick_run(tmp_path, "page", DOCS, BF16_AMD)), "--root", str(repo)])
    capsys.readouterr()
    assert script.main([str(quick_run(tmp_path, "old", DOCS, None)), "--root", str(repo), "--check"]) == 0
    assert "the run records no training precision, so not an exact comparison" in capsys.readouterr().out


def test_a_block_without_a_data_line_fails_and_says_to_regenerate_it(script, repo, tmp_path, capsys):
    """Today's quick block (rendered before blocks carried their numerics) must not pass silently."""
    run = quick_run(tmp_path, "run", DOCS, BF16_AMD)
    script.main([str(run), "--root", str(repo)])
    page = repo / "docs" / "main-job.md"
    page.write_text(
        "".join(ln for ln in page.read_text().splitlines(True) if not ln.startswith("<!-- results:data"))
    )
    capsys.readouterr()
    assert script.main([str(run), "--root", str(repo), "--check"]) == 1
    assert capsys.readouterr().out == (
        "docs/main-job.md block 'demo-results' predates the numerics key (it has no <!-- results:data line), "
        "so it cannot say which machine and precision its numbers need: regenerate it with "
        f"`python scripts/update_results.py {run}` and commit it\n"
    )


def test_agreement_needs_the_same_arms_conditions_and_episodes():
    page = BlockData(
        BF16_AMD, {"baseline": {"clean": (28, 50), "dim:0.7": (20, 50)}, "gaze": {"clean": (32, 50)}}
    )
    run = BlockData(FP32_AVX2, {"baseline": {"clean": (28, 60)}, "glc": {"clean": (30, 50)}})
    result = agreement(page, run)
    assert not result.agrees and result.cells == []
    assert result.problems == [
        "arm gaze is only in the page's block",
        "arm glc is only in the run's block",
        "baseline x dim:0.7 is only in the page's block",
        "baseline x clean: 50 episodes on the page, 60 in the run",
    ]
    same = agreement(page, page)
    assert (
        same.agrees
        and same.threshold == pytest.approx(0.01 / 3)
        and all(c.p == pytest.approx(1.0) for c in same.cells)
    )


def test_the_data_line_carries_the_key_counts_and_attention_and_reads_back(tmp_path):
    report = json.loads((quick_run(tmp_path, "run", DOCS, BF16_AMD) / "report.json").read_text())
    block = results_block(report, "figures/f.png")
    data = BlockData.read(block)
    assert data == BlockData.of_report(report, BLOCK_ALIGNMENT_KEYS)
    assert data.numerics == BF16_AMD and data.success == {
        "baseline": {"clean": (28, 50)},
        "gaze": {"clean": (32, 50)},
    }
    assert data.alignment["gaze"]["gaze_kl"] == round(report["alignment"]["gaze"]["gaze_kl"], 4)
    assert block.splitlines()[-1] == data.line() and data.line().startswith("<!-- results:data {")
    assert BlockData.read(block.replace(data.line(), "")) is None
    with pytest.raises(ValueError, match="one data line"):
        BlockData.read(block + data.line() + "\n")
    with pytest.raises(ValueError, match="not readable"):
        BlockData.read("<!-- results:data {} -->")


def test_a_scripts_markdown_file_becomes_a_block(script, repo, tmp_path):
    md = tmp_path / "horizon.md"
    md.write_text("## Horizon\n\n| arm | n |\n|---|---|\n| gaze | 3 |\n\n")
    assert script.main(["--file", str(md), "--marker", "demo-results", "--root", str(repo)]) == 0
    page = (repo / "docs" / "main-job.md").read_text()
    assert (
        "<!-- demo-results:start -->\n## Horizon\n\n| arm | n |\n|---|---|\n| gaze | 3 |\n<!-- demo-results:end -->"
        in page
    )
    assert "middle" in page and (repo / "docs" / "paper.md").read_text() == PAPER


# The repository's own pages (issue 34: findings first, one page per study, every block on exactly one page).

DOCS_PAGES = sorted((ROOT / "docs").glob("*.md"))
START = re.compile(r"<!-- ([A-Za-z0-9_.-]+):start -->")


def test_every_block_in_the_docs_is_on_exactly_one_page_and_readable(script):
    markers = {m.group(1) for page in DOCS_PAGES for m in START.finditer(page.read_text())}
    markers -= {"NAME"}  # prose that explains the marker lines
    assert {
        "demo-results",
        "quick-results",
        "paper-results",
        "paper-robustness",
        "libero-results",
        "lerobot-e2e",
    } <= markers
    for marker in sorted(markers):
        page = script.find_page(ROOT, marker)  # raises for none or two
        assert script.read_block(page, marker).strip(), marker


def _outside_code(text: str) -> str:
    """`text` without fenced code blocks and inline code spans."""
    text = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    return re.sub(r"`[^`\n]*`", "", text)


def _anchors(text: str) -> set[str]:
    """GitHub's heading anchors of a markdown page: lower case, punctuation dropped, spaces to hyphens, a
    repeated heading numbered -1, -2, ..."""
    seen: dict[str, int] = {}
    out = set()
    for line in re.sub(r"^```.*?^```", "", text, flags=re.S | re.M).splitlines():
        m = re.match(r"#{1,6} (.*)", line)
        if not m:
            continue
        slug = re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def test_every_local_link_and_anchor_on_the_docs_pages_and_readme_resolves():
    broken = []
    for page in [*DOCS_PAGES, ROOT / "README.md"]:
        for target in re.findall(r"\]\(([^)\s]+)\)", _outside_code(page.read_text())):
            if re.match(r"[a-z]+://", target):
                continue
            path, _, anchor = target.partition("#")
            file = (page.parent / path).resolve() if path else page
            if not file.exists():
                broken.append(f"{page.name}: {target} (no such file)")
            elif anchor and anchor not in _anchors(file.read_text()):
                broken.append(f"{page.name}: {target} (no such heading)")
    assert broken == []


def test_the_findings_page_lists_every_docs_page():
    findings = (ROOT / "docs" / "README.md").read_text()
    assert findings.startswith("# What the experiments found\n")
    contents = findings[findings.index("## The pages") :]
    assert [p.name for p in DOCS_PAGES if f"]({p.name})" not in contents] == []


NUMBER = re.compile(r"[+-]?\d+\.\d+|\d+/\d+")


def _blocks_text(script) -> str:
    markers = {m.group(1) for page in DOCS_PAGES for m in START.finditer(page.read_text())} - {"NAME"}
    return "\n".join(script.read_block(script.find_page(ROOT, m), m) for m in markers)


def test_the_numbers_in_the_findings_and_the_readme_results_are_quoted_from_blocks(script):
    """Every success count (k/n) and decimal in the prose of the findings page and of the README's Results
    section (outside blocks and code) occurs in a generated block: quoted, never computed or typed."""
    blocks = _blocks_text(script)
    readme = (ROOT / "README.md").read_text()
    results = readme[readme.index("## Results") : readme.index("## Your own policy")]
    prose = [
        (ROOT / "docs" / "README.md").read_text(),
        results.replace(script.read_block(ROOT / "README.md", "headline"), ""),
    ]
    numbers = {n for text in prose for n in NUMBER.findall(_outside_code(text))}
    assert len(numbers) > 10  # the findings quote their evidence
    assert sorted(n for n in numbers if n not in blocks) == []
