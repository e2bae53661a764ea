"""`gazereg.experiment.read_run`: the one reader of a finished experiment, from its run folder or its archive."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from gazereg import cli
from gazereg.experiment import FinishedRun, read_run
from gazereg.experiment.finished import STAGES
from gazereg.report.ids import RunId
from gazereg.runtime.errors import UsageError

ROOT = Path(__file__).resolve().parents[1]
ARCHIVE = ROOT / "docs" / "records" / "paper-abl-b"


def test_the_reader_reads_a_committed_archive():
    run = read_run(ARCHIVE)
    assert isinstance(run, FinishedRun) and run.archived
    assert run.runs == tuple(RunId("baseline", s) for s in (0, 1, 2))
    assert run.checkpoints == {r: None for r in run.runs}  # an archive keeps no checkpoints
    assert (run.tasks, run.env, run.arms, run.train_seeds) == (
        ("reach-v3", "button-press-topdown-v3"),
        "metaworld",
        ("baseline",),
        (0, 1, 2),
    )
    assert (run.camera, run.train_steps, run.max_steps, run.gaze_layers) == ("corner2", 16000, 120, (-2, -1))
    assert run.config["eval"]["episodes"] == 50
    # 2 tasks x 50 setups x 3 training seeds under each of 3 conditions, as report.json counted them
    by_condition = run.episodes_by_condition()
    assert list(by_condition) == ["clean", "dim:0.7", "gaussian_noise:0.5"]
    for condition, records in by_condition.items():
        cell = run.report["success"]["baseline"][condition]
        assert len(records) == cell["n"] == 300
        assert sum(r["success"] for r in records) == cell["successes"]
    assert len(run.episodes()) == 900
    steps = {RunId.parse(r["arm"]).step for r in run.episodes("converge")}
    assert None not in steps and max(steps) < run.train_steps
    assert set(run.stages) == set(STAGES)
    assert run.stage_times == pytest.approx(
        {s: v for s, v in run.report["stage_times_s"].items() if s != "report"}
    )
    assert run.date == json.loads((ARCHIVE / "archive.json").read_text())["date"] == run.report["date"]
    metrics = run.metrics(RunId("baseline", 1))
    assert metrics and metrics[-1]["step"] == run.train_steps
    outputs = run.stage_outputs()
    assert len(outputs.episodes) == 900 and set(outputs.metrics_files) == set(run.runs)
    with pytest.raises(UsageError, match="is an archive .*no checkpoints"):
        run.eval_config(out="x")
    with pytest.raises(UsageError, match="keeps no demonstrations"):
        run.collect_config()


def test_the_reader_refuses_what_is_not_a_finished_run_in_one_line(tmp_path):
    cases = []
    cases.append((tmp_path / "absent", "is not a folder"))
    (tmp_path / "empty").mkdir()
    cases.append((tmp_path / "empty", "neither a finished experiment folder nor an archive of one"))
    cut = tmp_path / "cut"
    shutil.copytree(ARCHIVE, cut)
    (cut / "stages" / "eval.json").unlink()
    cases.append((cut, "cut has not finished its eval stage"))
    pooled = tmp_path / "pooled"
    pooled.mkdir()
    shutil.copyfile(ARCHIVE / "config.json", pooled / "config.json")
    (pooled / "pooled.json").write_text("{}")
    cases.append((pooled, "is a pooled report"))
    for path, message in cases:
        with pytest.raises(UsageError, match=message) as e:
            read_run(path)
        assert "\n" not in str(e.value)


@pytest.mark.sim
def test_a_run_folder_and_its_archive_read_the_same(finished_experiment, tmp_path, monkeypatch):
    """A finished folder (the smoke experiment) and its archive give the same records; the folder's
    checkpoints are found in it even from another working directory, and its evaluation settings rebuild."""
    kept = tmp_path / "kept"
    assert cli.main(["archive", str(finished_experiment), "--out", str(kept)]) == 0
    run, archived = read_run(finished_experiment), read_run(kept)
    assert not run.archived and archived.archived
    assert run.runs == archived.runs == (RunId("baseline", 0), RunId("gaze", 0))
    assert run.config == archived.config and run.stages == archived.stages
    assert run.episodes() == archived.episodes() and run.episodes("converge") == archived.episodes("converge")
    assert run.date == archived.date and run.report == archived.report
    for r in run.runs:
        assert run.metrics(r) == archived.metrics(r) != []
    monkeypatch.chdir(tmp_path)
    for r, path in run.checkpoints.items():
        assert path is not None and path.is_dir() and (path / "config.json").is_file()
        assert path.parent.parent == finished_experiment / "train" / f"{r.arm}_s{r.seed}"
    cfg = run.eval_config(tmp_path / "again", conditions=("dim:0.7",), videos=0)
    assert cfg.tasks == run.tasks and cfg.max_steps == run.max_steps and cfg.out == tmp_path / "again"
    assert cfg.conditions == ("dim:0.7",) and len(cfg.checkpoints) == 2
    assert run.collect_config("heldout")["tasks"] == list(run.tasks)
