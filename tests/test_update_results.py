"""scripts/update_results.py: results blocks go into docs/results.md, the README's headline is the head of the
paper-results block, and nothing outside the markers changes."""

import importlib.util
import json
import shutil
from pathlib import Path

import pytest

from gazereg.report import headline_lines, results_block

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


def test_check_passes_on_the_same_numbers_and_fails_on_others(script, repo, run, capsys):
    assert script.main([str(run), "--root", str(repo)]) == 0
    page = repo / "docs" / "results.md"
    assert script.main([str(run), "--root", str(repo), "--check"]) == 0
    text = page.read_text()
    start = text.index("<!-- quick-results:start -->\n") + len("<!-- quick-results:start -->\n")
    first_line_end = text.index("\n", start)
    page.write_text(text[:start] + "Latest run: another date and wall time" + text[first_line_end:])
    assert script.main([str(run), "--root", str(repo), "--check"]) == 0  # the run line may differ
    page.write_text(text.replace("| baseline | 0/2", "| baseline | 1/2", 1))
    assert page.read_text() != text
    assert script.main([str(run), "--root", str(repo), "--check"]) == 1
    assert "does not reproduce" in capsys.readouterr().out


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
