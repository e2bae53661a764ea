"""The paper-layout table (gazereg.report.paper_table, scripts/paper_table.py; issue 37): each row's arms
recounted from its run's episodes with Wilson intervals, gaze against the baseline and against uniform paired by
setup, robustness by the paper's axes, the paper's second-hand figures beside ours, and bad input refused in one
line. The runs are a committed archive (docs/records/paper-abl-b) given another simulator, tasks, arms and
episodes."""

import gzip
import json
import re
import shutil
from pathlib import Path

import pytest

from gazereg.evaluation.stats import mcnemar_exact, unit_mean_difference
from gazereg.experiment.finished import read_run
from gazereg.experiment.pooled import pooled_runs, read_results
from gazereg.report.paper_table import PAPER, axis_of, paper_table
from gazereg.runtime.errors import UsageError

ROOT = Path(__file__).resolve().parents[1]


def fake_run(dest, env, tasks, outcomes, seed=0):
    """An archive of a `env` run over `tasks` whose final evaluation is `outcomes`: {(arm, condition, task):
    successes per setup (1000..)}, training seed `seed`."""
    shutil.copytree(ROOT / "docs" / "records" / "paper-abl-b", dest)
    cfg = json.loads((dest / "config.json").read_text())
    cfg.update(env=env, tasks=list(tasks), arms=sorted({arm for arm, _, _ in outcomes}), train_seeds=[seed])
    (dest / "config.json").write_text(json.dumps(cfg))
    train = dest / "stages" / "train.json"
    record = json.loads(train.read_text())
    record["runs"] = {f"{arm}@s{seed}": {} for arm in cfg["arms"]}
    train.write_text(json.dumps(record))
    episodes = [
        {
            "arm": f"{arm}@s{seed}",
            "condition": cond,
            "task": task,
            "seed": 1000 + i,
            "success": bool(s),
            "length": 9,
        }
        for (arm, cond, task), xs in outcomes.items()
        for i, s in enumerate(xs)
    ]
    (dest / "eval" / "eval_info.json.gz").write_bytes(
        gzip.compress(json.dumps({"episodes": episodes}).encode())
    )
    return read_run(dest)


BASE = [1, 1, 1, 1, 1, 0, 0, 0, 0, 0]
GAZE = [1, 1, 1, 1, 1, 1, 1, 1, 0, 0]
UNIFORM = [1, 1, 1, 1, 1, 1, 1, 0, 0, 0]


@pytest.fixture
def spatial(tmp_path):
    task = "libero_spatial/0"
    return fake_run(
        tmp_path / "spatial",
        "libero",
        ("libero_spatial",),
        {
            ("baseline", "clean", task): BASE,
            ("gaze", "clean", task): GAZE,
            ("uniform", "clean", task): UNIFORM,
            ("baseline", "dim:0.7", task): [1, 0],
            ("gaze", "dim:0.7", task): [0, 0],
            ("uniform", "dim:0.7", task): [1, 1],
        },
    )


def line(text, start):
    return next(x for x in text.splitlines() if x.startswith(start))


def test_a_suite_row_is_recounted_from_its_episodes(spatial):
    text = paper_table({"libero_spatial": spatial})
    row = line(text, "| LIBERO-Spatial |").split(" | ")
    assert row[1] == "1"  # one training seed
    assert row[2].startswith("50.0 [") and row[2].endswith("(5/10)")
    assert row[3].startswith("80.0 [") and row[3].endswith("(8/10)")
    assert row[4] == "not run"  # no glc arm
    assert row[5].endswith("(7/10)")
    p = mcnemar_exact([bool(x) for x in GAZE], [bool(x) for x in BASE])["p_value"]
    assert row[6].startswith("+30.0 [") and row[6].endswith(f"p {p:.2g}")
    assert row[7] == "one seed"
    assert row[8] == f"p {mcnemar_exact(GAZE, UNIFORM)['p_value']:.2g}"
    assert row[9] == "pi0 85.9 -> 95.5; OpenVLA 76.0 -> 82.2 |"


def test_seeds_that_disagree_show_per_seed_and_widen_the_seed_level_interval(spatial, tmp_path):
    """Seed 1 reverses seed 0 (gaze and baseline swap outcomes): pooled, the episodes' McNemar sees no
    difference; per seed the row shows +30 and -30 points and their mean with the t interval over two seeds."""
    task = "libero_spatial/0"
    flipped = fake_run(
        tmp_path / "s1",
        "libero",
        ("libero_spatial",),
        {
            ("baseline", "clean", task): GAZE,
            ("gaze", "clean", task): BASE,
            ("uniform", "clean", task): UNIFORM,
        },
        seed=1,
    )
    text = paper_table({"libero_spatial": pooled_runs([spatial, flipped])})
    row = line(text, "| LIBERO-Spatial |").split(" | ")
    assert row[1] == "2"
    assert row[2].endswith("(13/20)") and row[3].endswith("(13/20)")
    assert row[6].startswith("+0.0 [") and row[6].endswith("p 1")
    half = 100 * unit_mean_difference([0.3, -0.3])["ci95"][1]
    assert half > 300  # two seeds of opposite sign: t with one degree of freedom
    assert row[7] == f"+30.0, -30.0; +0.0 [{-half:+.1f}, {half:+.1f}]"


def test_rows_without_a_run_show_the_paper_only_and_robustness_only_the_runs(spatial):
    text = paper_table({"libero_spatial": spatial})
    assert line(text, "| LIBERO-Goal |").startswith("| LIBERO-Goal | not run |")
    assert line(text, "| LIBERO-Goal |").endswith("| OpenVLA 72.5 -> 76.8 |")
    assert line(text, "| LIBERO-10 |").endswith("| pi0 +11.8; OpenVLA 45.9 -> 51.5 |")
    assert line(text, "| Aloha insertion |").endswith("| not reported |")
    lighting = text[text.index("Robustness, lighting (`dim:0.7`): ") : text.index("Robustness, camera noise")]
    assert "(1/2)" in line(lighting, "| LIBERO-Spatial |") and "(2/2)" in line(lighting, "| LIBERO-Spatial |")
    assert line(lighting, "| LIBERO-Spatial |").endswith("| pi0 77.2 -> 89.1 |")
    assert (
        line(lighting, "| LIBERO-Goal |") == "| LIBERO-Goal | not run |  |  |  |  |  |  |  | not reported |"
    )
    noise = text[text.index("Robustness, camera noise: ") :]  # no run evaluated it: the paper's figures only
    assert line(noise, "| LIBERO-Spatial |").startswith("| LIBERO-Spatial | not run |")
    assert line(noise, "| LIBERO-Spatial |").endswith("| pi0 82.1 -> 91.3 |")
    assert line(noise, "| LIBERO-Goal |").endswith("| pi0 79.6 -> 88.9 |")
    assert [axis_of(c) for c in ("clean", "dim:0.7", "gaussian_noise:0.5", "blur:2")] == [
        "clean",
        "lighting",
        "camera noise",
        "blur:2",
    ]
    assert all(f.row in {"libero_spatial", "libero_object", "libero_goal", "libero_10"} for f in PAPER)


def test_one_aloha_run_fills_both_aloha_rows_by_task(tmp_path):
    cube, insertion = "AlohaTransferCube-v0", "AlohaInsertion-v0"
    run = fake_run(
        tmp_path / "aloha",
        "aloha",
        (cube, insertion),
        {
            ("baseline", "clean", cube): [1, 0, 0, 0],
            ("gaze", "clean", cube): [1, 1, 0, 0],
            ("baseline", "clean", insertion): [0, 0, 0, 0],
            ("gaze", "clean", insertion): [0, 0, 0, 1],
        },
    )
    text = paper_table({"aloha": run})
    assert "(1/4)" in line(text, "| Aloha transfer cube |") and "(2/4)" in line(
        text, "| Aloha transfer cube |"
    )
    assert "(0/4)" in line(text, "| Aloha insertion |") and "(1/4)" in line(text, "| Aloha insertion |")
    lighting = text[text.index("Robustness, lighting: ") :]  # the run evaluated clean only
    assert line(lighting, "| Aloha transfer cube |").startswith("| Aloha transfer cube | not run |")


def test_bad_rows_are_refused(spatial, tmp_path):
    with pytest.raises(UsageError, match="a libero run, row aloha_insertion needs a aloha run"):
        paper_table({"aloha_insertion": spatial})
    with pytest.raises(UsageError, match="unknown paper-table row 'libero_90'"):
        paper_table({"libero_90": spatial})
    aloha = fake_run(
        tmp_path / "cube",
        "aloha",
        ("AlohaTransferCube-v0",),
        {("baseline", "clean", "AlohaTransferCube-v0"): [1]},
    )
    with pytest.raises(UsageError, match="no AlohaInsertion-v0 episodes for row aloha_insertion"):
        paper_table({"aloha": aloha})


def test_the_script_writes_the_table_or_refuses_in_one_line(spatial, tmp_path, capsys, load_script):
    script = load_script("scripts/paper_table.py", "paper_table_script")
    out = tmp_path / "table.md"
    assert script.main(["--run", f"libero_spatial={spatial.path}", "--out", str(out)]) == 0
    assert out.read_text() == paper_table({"libero_spatial": read_run(spatial.path)})
    capsys.readouterr()
    assert (
        script.main(["--run", f"libero_spatial={tmp_path / 'nothing'}", "--out", str(tmp_path / "x.md")]) == 2
    )
    err = capsys.readouterr().err
    assert err.startswith("paper_table.py: error: ") and err.count("\n") == 1
    assert script.main(["--run", "libero_spatial"]) == 2
    assert not (tmp_path / "x.md").exists()


def test_sittings_are_pooled_into_one_row(spatial, tmp_path, load_script):
    """A suite run in sittings (baseline and gaze in one folder, uniform in another) gives the row one folder of
    all three would: given folder by folder to the script, or as a pooled report's folder; folders of other
    tasks, or one run in two folders, are refused."""
    task = "libero_spatial/0"
    core = fake_run(
        tmp_path / "s0",
        "libero",
        ("libero_spatial",),
        {("baseline", "clean", task): BASE, ("gaze", "clean", task): GAZE},
    )
    more = fake_run(tmp_path / "s0-glc", "libero", ("libero_spatial",), {("uniform", "clean", task): UNIFORM})
    clean = lambda text: line(text, "| LIBERO-Spatial |")  # noqa: E731
    whole = clean(paper_table({"libero_spatial": spatial}))
    assert clean(paper_table({"libero_spatial": pooled_runs([core, more])})) == whole
    pooled = tmp_path / "pooled"
    pooled.mkdir()
    (pooled / "pooled.json").write_text(json.dumps({"folders": [str(core.path), str(more.path)]}))
    assert clean(paper_table({"libero_spatial": read_results(pooled)})) == whole
    assert read_results(core.path).path == core.path  # a single folder is read as itself
    script = load_script("scripts/paper_table.py", "paper_table_script")
    out = tmp_path / "t.md"
    assert script.main(["--run", f"libero_spatial={core.path},{more.path}", "--out", str(out)]) == 0
    assert clean(out.read_text()) == whole
    with pytest.raises(UsageError, match=r"baseline@s0 is in both .*s0 and .*spatial"):
        pooled_runs([core, spatial])
    other = fake_run(tmp_path / "o", "libero", ("libero_object",), {("uniform", "clean", task): [1]})
    with pytest.raises(UsageError, match="not one experiment with"):
        pooled_runs([core, other])


PAGE_RUN = re.compile(r"--run (\w+)=(docs/records/[\w./,-]+)")
"""a `--run ROW=docs/records/NAME[,NAME...]` of the `scripts/paper_table.py` command docs/paper-benchmarks.md
gives for its block"""


def test_the_committed_block_is_the_table_of_the_archives_its_page_command_names(script):
    page = ROOT / "docs" / "paper-benchmarks.md"
    block = script.read_block(page, "paper-table")
    named = dict(PAGE_RUN.findall(page.read_text().split("<!-- paper-table:start -->")[0]))
    assert "libero_spatial" in named  # the command is on the page, before its block
    runs = {
        row: pooled_runs([read_run(ROOT / f) for f in folders.split(",")]) for row, folders in named.items()
    }
    assert block.strip() == paper_table(runs).strip()
