import json
from pathlib import Path

import pytest

from gazereg import cli
from gazereg.experiment.compare import compare_runs, main
from gazereg.experiment.finished import STAGES, read_run
from gazereg.report.compare import compare_markdown, compare_records, compare_tasks
from gazereg.runtime.config import config_diff
from gazereg.runtime.errors import UsageError
from gazereg.training.numerics import record_numerics

ROOT = Path(__file__).resolve().parents[1]
ARCHIVE_B, ARCHIVE_C = ROOT / "docs" / "records" / "paper-abl-b", ROOT / "docs" / "records" / "paper-abl-c"


def records(arm, successes, condition="clean", task="reach-v3", start=1000, distance=None):
    out = []
    for i, s in enumerate(successes):
        r = {"arm": arm, "task": task, "condition": condition, "seed": start + i, "success": bool(s)}
        if distance is not None:
            r["min_distance"] = distance
        out.append(r)
    return out


def write_run(root, name, config, episodes, curves=None):
    """A finished experiment folder as far as `compare` reads one: its config, stage records, evaluation."""
    run = root / name
    (run / "eval").mkdir(parents=True)
    (run / "stages").mkdir()
    for stage in STAGES[:-1]:
        (run / "stages" / f"{stage}.json").write_text(json.dumps({"seconds": 1.0}))
    (run / "config.json").write_text(json.dumps(config))
    (run / "eval" / "eval_info.json").write_text(json.dumps({"episodes": episodes}))
    if curves is not None:
        (run / "report.json").write_text(json.dumps({"convergence": {"arms": curves}}))
    return run


def test_config_diff_names_dotted_leaves_and_ignores_out():
    a = {"out": "runs/a", "train": {"steps": 4000, "optim": {"lr": 1e-3}}, "tasks": ["reach-v3"]}
    b = {"out": "runs/b", "train": {"steps": 6000, "optim": {"lr": 1e-3}}, "tasks": ["reach-v3"], "new": 1}
    assert config_diff(a, b, ignore=("out",)) == {"train.steps": [4000, 6000], "new": [None, 1]}
    assert config_diff(a, b, ignore=("out", "train.steps")) == {"new": [None, 1]}  # dotted keys too
    assert config_diff(a, b)["out"] == ["runs/a", "runs/b"]


def test_compare_pairs_each_arm_by_seed_task_and_setup():
    a = records("gaze@s0", [0] * 10, distance=0.2) + records("baseline@s0", [1, 0] * 5)
    b = records("gaze@s0", [1] * 8 + [0] * 2, distance=0.1) + records("baseline@s0", [1, 0] * 5)
    b += records("gaze@s1", [1] * 10)  # a training seed A never ran: unpaired, left out of the test
    rows = compare_records(a, b)
    g = rows["gaze | clean"]
    assert g["pairs"] == 10 and g["b_only"] == 8 and g["a_only"] == 0 and g["mcnemar_p"] < 0.01
    assert g["rate_diff"] == pytest.approx(0.8) and 0.3 < g["rate_ci95"][0] < 0.8 < g["rate_ci95"][1]
    assert g["a"]["successes"] == 0 and g["b"]["successes"] == 18  # the success cells pool every seed
    assert g["distance"]["mean_diff"] == pytest.approx(-0.1)
    base = rows["baseline | clean"]
    assert base["a_only"] == base["b_only"] == 0 and base["mcnemar_p"] == 1.0 and base["distance"] is None


def test_compare_breaks_each_arm_down_by_task_when_the_runs_share_several():
    a = records("gaze@s0", [0] * 6, task="reach-v3") + records("gaze@s0", [1] * 6, task="push-v3")
    b = records("gaze@s0", [1] * 6, task="reach-v3") + records("gaze@s0", [1] * 3 + [0] * 3, task="push-v3")
    b += records("gaze@s0", [1] * 4, task="pick-place-v3")  # A never ran it: no row
    tasks = compare_tasks(a, b)
    assert list(tasks) == ["reach-v3", "push-v3"]
    assert (
        tasks["reach-v3"]["gaze | clean"]["b_only"] == 6 and tasks["reach-v3"]["gaze | clean"]["a_only"] == 0
    )
    assert tasks["push-v3"]["gaze | clean"]["a_only"] == 3 and tasks["push-v3"]["gaze | clean"]["b"]["n"] == 6
    pooled = compare_records(a, b)["gaze | clean"]
    assert (pooled["a_only"], pooled["b_only"]) == (3, 6)  # the two tasks' discordant pairs together
    assert (
        compare_tasks(records("gaze@s0", [1] * 3), records("gaze@s0", [0] * 3)) == {}
    )  # one task: no breakdown


def test_compare_markdown_has_a_per_task_table_only_for_several_tasks(tmp_path):
    two = records("gaze@s0", [0, 1], task="reach-v3") + records("gaze@s0", [1, 1], task="push-v3")
    a = write_run(tmp_path, "a", {"out": "a"}, two)
    b = write_run(tmp_path, "b", {"out": "b"}, records("gaze@s0", [1, 1], task="reach-v3") + two[2:])
    text = compare_markdown(compare_runs(a, b))
    assert (
        "Per task:" in text
        and "| reach-v3 | gaze | clean | 1/2 = 0.50" in text
        and "| push-v3 | gaze |" in text
    )
    one = write_run(tmp_path, "c", {"out": "c"}, records("gaze@s0", [0, 1]))
    assert "Per task:" not in compare_markdown(compare_runs(one, one))


def test_compare_without_shared_setups_names_both_sides():
    with pytest.raises(ValueError, match=r"share no evaluated episode.*1000\.\.1004.*2000\.\.2004"):
        compare_records(records("gaze@s0", [1] * 5), records("gaze@s0", [1] * 5, start=2000))


def test_compare_runs_cli_writes_markdown_and_json(tmp_path, capsys):
    curves = {"gaze": {"steps": [1000, 2000], "rates": [0.25, 0.5], "ci95": [[0, 1], [0, 1]]}}
    a = write_run(tmp_path, "a", {"out": "a", "train": {"steps": 4000}}, records("gaze@s0", [0, 1, 0, 1]))
    b = write_run(tmp_path, "b", {"out": "b", "train": {"steps": 6000}}, records("gaze@s0", [1] * 4), curves)
    result = compare_runs(a, b)
    assert result["differences"] == {"train.steps": [4000, 6000]}
    assert result["curves"] == {"a": {}, "b": {"gaze": {"steps": [1000, 2000], "rates": [0.25, 0.5]}}}
    text = compare_markdown(result)
    assert "`train.steps` 4000 -> 6000" in text and "| gaze | clean | 2/4 = 0.50" in text
    assert "| 0 / 2 | +0.50 [" in text  # B solved the 2 setups A missed: the paired difference
    assert "- B gaze: 1000: 0.25, 2000: 0.50" in text
    assert text.startswith("## ") and compare_markdown(result, level=3).startswith(
        f"### {b} (B) against {a} (A)"
    )

    out = tmp_path / "cmp" / "budget.md"
    assert main([str(a), str(b), "--out", str(out)]) == 0
    assert out.read_text() == text and json.loads(out.with_suffix(".json").read_text())["rows"]
    assert "2/4 = 0.50" in capsys.readouterr().out


def test_a_key_added_since_the_older_run_counts_at_its_default(tmp_path):
    """A run saved before `train.photometric` existed trained without it: against a newer run that keeps it
    at its default nothing differs; a newer run that sets it differs from the default, named as such."""
    zeros = {"brightness": 0.0, "contrast": 0.0, "saturation": 0.0}
    old = write_run(tmp_path, "old", {"out": "old", "train": {"steps": 3000}}, records("gaze@s0", [0, 1]))
    same = {"out": "same", "train": {"steps": 3000, "photometric": zeros}}
    new = write_run(tmp_path, "same", same, records("gaze@s0", [1, 1]))
    assert compare_runs(old, new)["differences"] == {}
    assert compare_runs(new, old)["differences"] == {}
    jitter = {"out": "jit", "train": {"steps": 3000, "photometric": {**zeros, "brightness": 0.2}}}
    jit = write_run(tmp_path, "jit", jitter, records("gaze@s0", [1, 1]))
    assert compare_runs(old, jit)["differences"] == {"train.photometric.brightness": [0.0, 0.2]}


def test_a_precision_saved_as_auto_is_compared_as_the_precision_its_runs_trained_in(tmp_path):
    """ "auto" is bf16 on a CPU with native bf16 and float32 elsewhere: a run saved with it differs from a
    pinned run only when its runs recorded training in another precision (or recorded nothing)."""
    auto = write_run(
        tmp_path, "auto", {"out": "a", "train": {"mixed_precision": "auto"}}, records("gaze@s0", [1])
    )
    pinned = write_run(
        tmp_path, "no", {"out": "b", "train": {"mixed_precision": "no"}}, records("gaze@s0", [1])
    )
    assert compare_runs(auto, pinned)["differences"] == {"train.mixed_precision": ["auto", "no"]}  # no record
    record_numerics(auto / "train" / "gaze_s0", "no", start=0)
    assert compare_runs(auto, pinned)["differences"] == {}
    record_numerics(auto / "train" / "gaze_s0", "bf16", start=0)
    assert compare_runs(auto, pinned)["differences"] == {"train.mixed_precision": ["bf16", "no"]}


def test_compare_a_folder_that_is_no_finished_run_says_so_in_one_line(tmp_path, capsys):
    run = tmp_path / "unfinished"
    run.mkdir()
    with pytest.raises(UsageError, match=r"neither a finished experiment folder nor an archive of one"):
        compare_runs(run, ARCHIVE_B)
    (run / "config.json").write_text("{}")
    with pytest.raises(UsageError, match=r"unfinished has not finished its demos stage"):
        compare_runs(ARCHIVE_B, run)
    assert cli.main(["compare", str(ARCHIVE_B), str(run)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("gazereg compare: error:") and "has not finished its demos stage" in err
    assert len(err.splitlines()) == 1


def test_compare_reads_committed_archives(tmp_path, capsys):
    """`gazereg compare` on two archives (only eval_info.json.gz, no checkpoints): the baseline against itself
    pairs every clean and perturbed setup with no discordant pair, and its curves come from report.json."""
    report = read_run(ARCHIVE_B).report
    out = tmp_path / "self.md"
    assert cli.main(["compare", str(ARCHIVE_B), str(ARCHIVE_B), "--out", str(out)]) == 0
    result = json.loads(out.with_suffix(".json").read_text())
    assert result["differences"] == {}
    assert set(result["rows"]) == {f"baseline | {c}" for c in ("clean", "dim:0.7", "gaussian_noise:0.5")}
    clean = result["rows"]["baseline | clean"]
    assert clean["pairs"] == report["success"]["baseline"]["clean"]["n"] == 300
    assert (
        clean["a"]["successes"]
        == clean["b"]["successes"]
        == report["success"]["baseline"]["clean"]["successes"]
    )
    assert clean["a_only"] == clean["b_only"] == 0 and clean["mcnemar_p"] == 1.0
    steps = report["convergence"]["arms"]["baseline"]["steps"]
    assert result["curves"]["a"]["baseline"]["steps"] == result["curves"]["b"]["baseline"]["steps"] == steps
    assert "| baseline | clean | 174/300" in capsys.readouterr().out
    # two archives of other arms share no episode: one line, exit 2
    assert cli.main(["compare", str(ARCHIVE_B), str(ARCHIVE_C)]) == 2
    err = capsys.readouterr().err
    assert "share no evaluated episode" in err and len(err.strip().splitlines()) == 1


def test_the_per_task_rows_carry_each_tasks_instruction_when_a_report_states_it(tmp_path):
    two = records("gaze@s0", [0, 1], task="reach-v3") + records("gaze@s0", [1, 1], task="push-v3")
    a = write_run(tmp_path, "a", {"out": "a"}, two)
    b = write_run(tmp_path, "b", {"out": "b"}, two)
    said = {"reach-v3": "Reach the goal.", "push-v3": "Push the puck to the goal."}
    (b / "report.json").write_text(json.dumps({"demos": {"instructions": said}}))
    text = compare_markdown(compare_runs(a, b))
    assert "| reach-v3: Reach the goal. | gaze | clean |" in text
    assert "| push-v3: Push the puck to the goal. | gaze | clean |" in text
