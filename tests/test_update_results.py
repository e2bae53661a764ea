"""scripts/update_results.py: results blocks go into docs/results.md, the README's headline is the head of the
paper-results block, nothing outside the markers changes, and --check compares a run with a block exactly when
their numerics keys are equal, by a stated test of agreement when they differ, and refuses a block without
its data line (issue 33)."""

import importlib.util
import json
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


@pytest.fixture(scope="module")
def script():
    spec = importlib.util.spec_from_file_location("update_results", ROOT / "scripts" / "update_results.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def repo(tmp_path):
    """A repository with a README headline block and a results page holding two blocks."""
    (tmp_path / "docs").mkdir()
    (tmp_path / "README.md").write_text("# x\n<!-- headline:start -->\nold\n<!-- headline:end -->\nend\n")
    (tmp_path / "docs" / "results.md").write_text(
        "# Results\n<!-- quick-results:start -->\nold quick\n<!-- quick-results:end -->\nmiddle\n"
        "<!-- paper-results:start -->\nold paper\n<!-- paper-results:end -->\nend\n"
    )
    return tmp_path


@pytest.fixture
def run(tmp_path):
    run = tmp_path / "run"
    report = json.loads((GOLDEN / "smoke_report.json").read_text())
    (run / "figures").mkdir(parents=True)
    (run / report["figures"]["attention"]).write_bytes(b"png")
    (run / "report.json").write_text(json.dumps(report))
    return run


def test_a_run_block_goes_into_the_results_page_with_its_figure(script, repo, run):
    assert script.main([str(run), "--root", str(repo)]) == 0
    page = (repo / "docs" / "results.md").read_text()
    report = json.loads((run / "report.json").read_text())
    block = results_block(report, "figures/quick-results-attention.png")
    assert page == (
        "# Results\n<!-- quick-results:start -->\n" + block + "<!-- quick-results:end -->\nmiddle\n"
        "<!-- paper-results:start -->\nold paper\n<!-- paper-results:end -->\nend\n"
    )
    assert (repo / "docs" / "figures" / "quick-results-attention.png").read_bytes() == b"png"
    assert "old" in (repo / "README.md").read_text()  # only paper-results feeds the headline


def test_the_paper_block_refreshes_the_readme_headline(script, repo, run):
    script.main([str(run), "--marker", "paper-results", "--root", str(repo)])
    report = json.loads((run / "report.json").read_text())
    readme = (repo / "README.md").read_text()
    head = "\n".join(headline_lines(report))
    assert readme == f"# x\n<!-- headline:start -->\n{head}\n\n<!-- headline:end -->\nend\n"
    assert "![attention](figures/paper-results-attention.png)" in (repo / "docs" / "results.md").read_text()


def test_headline_only_copies_from_the_results_page(script, repo, run):
    page = repo / "docs" / "results.md"
    block = results_block(json.loads((run / "report.json").read_text()), "figures/f.png")
    script.replace_block(page, "paper-results", block)
    assert script.main(["--headline", "--root", str(repo)]) == 0
    assert script.read_block(repo / "README.md", "headline") == script.headline_of(block)
    assert script.headline_of(block).startswith("Latest `smoke` run")


def test_a_page_without_the_block_is_refused(script, repo, run):
    with pytest.raises(ValueError, match="has no <!-- paper-budget:start -->"):
        script.main([str(run), "--marker", "paper-budget", "--root", str(repo)])
    with pytest.raises(SystemExit):
        script.main(["--root", str(repo)])  # no run and no --headline


def test_the_repositorys_readme_headline_is_the_head_of_its_paper_block(script, tmp_path):
    """The README's headline block is what the script makes of docs/results.md, not typed text."""
    readme_headline = script.read_block(ROOT / "README.md", "headline")
    paper = script.read_block(ROOT / "docs" / "results.md", "paper-results")
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
    assert "reproduces docs/results.md block 'quick-results' exactly (same numerics key: bf16 mixed" in (
        capsys.readouterr().out
    )
    page = repo / "docs" / "results.md"
    text = page.read_text()
    start = text.index("<!-- quick-results:start -->\n") + len("<!-- quick-results:start -->\n")
    page.write_text(text[:start] + "Latest run: another date and wall time" + text[text.index("\n", start) :])
    assert script.main([str(page_run), "--root", str(repo), "--check"]) == 0  # the run line may differ
    # one success more: chance explains it, but equal keys must give equal numbers
    closer = quick_run(tmp_path, "closer", {"baseline": (29, 50), "gaze": (32, 50)}, BF16_AMD)
    capsys.readouterr()
    assert script.main([str(closer), "--root", str(repo), "--check"]) == 1
    out = capsys.readouterr().out
    assert "does not reproduce docs/results.md block 'quick-results' exactly although both have" in out
    assert "29/50" in out
    page.write_text(text.replace("| baseline | 28/50", "| baseline | 27/50", 1))  # a table typed by hand
    assert script.main([str(page_run), "--root", str(repo), "--check"]) == 1


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
    assert "agrees with docs/results.md block 'quick-results' (not identical: different numerics)" in out


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
        f"{avx2} does not agree with docs/results.md block 'quick-results': baseline x clean: page 40/50, "
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
    page = repo / "docs" / "results.md"
    page.write_text(
        "".join(ln for ln in page.read_text().splitlines(True) if not ln.startswith("<!-- results:data"))
    )
    capsys.readouterr()
    assert script.main([str(run), "--root", str(repo), "--check"]) == 1
    assert capsys.readouterr().out == (
        "docs/results.md block 'quick-results' predates the numerics key (it has no <!-- results:data line), "
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
    assert script.main(["--file", str(md), "--marker", "quick-results", "--root", str(repo)]) == 0
    page = (repo / "docs" / "results.md").read_text()
    assert (
        "<!-- quick-results:start -->\n## Horizon\n\n| arm | n |\n|---|---|\n| gaze | 3 |\n<!-- quick-results:end -->"
        in page
    )
    assert "old paper" in page and "middle" in page
