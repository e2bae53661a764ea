"""A report names the numerics key its runs recorded when they trained (train/RUN/numerics.json), not the key of
the machine that builds the report: one key when every run trained on one machine, "trained on several
machines" (no key, so update_results --check tests agreement) when they differ, and the report machine's key in
the runs' precision, as before, for runs made before the record."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from matplotlib.image import imsave

from gazereg.experiment.archive import archived_files
from gazereg.experiment.finished import FinishedRun, read_run
from gazereg.experiment.pool import merge_outputs
from gazereg.report import machine_summary, results_block, tables
from gazereg.report.blockdata import BlockData
from gazereg.report.build import ReportSpec, StageOutputs, build_report
from gazereg.report.ids import RunId
from gazereg.report.sections import numerics_text
from gazereg.runtime import hardware
from gazereg.runtime.hardware import NumericsKey
from gazereg.training.numerics import NUMERICS_FILE, TrainingAttempt, record_numerics

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = Path(__file__).parent / "report_golden"
INTEL = NumericsKey("no", "AVX512", (), "GenuineIntel", "2.13.0+cpu")
AMD = NumericsKey("no", "AVX2", (), "AuthenticAMD", "2.13.0+cpu")
XEON = "Intel(R) Xeon(R) Platinum 8481C CPU @ 2.70GHz"
RUNS = (RunId("baseline", 0), RunId("gaze", 0))


@pytest.fixture
def report_machine_is_amd(monkeypatch):
    """The machine building the report seen as an AMD EPYC with AVX2 only (its own key is AMD's)."""
    for module in (hardware, tables):
        monkeypatch.setattr(module, "cpu_flags", lambda: frozenset({"avx2", "fma"}))
        monkeypatch.setattr(module, "cpu_identity", lambda: ("AuthenticAMD", "AMD EPYC 7B13"))
    monkeypatch.setattr(torch.backends.cpu, "get_cpu_capability", lambda: "AVX2")
    monkeypatch.setattr(torch, "__version__", "2.13.0+cpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)


def on(*keys):
    """A run's attempts, one per key, each from the step after the last (the Xeon's model for INTEL)."""
    return tuple(TrainingAttempt(i + 1, 10 * i, k, XEON if k == INTEL else None) for i, k in enumerate(keys))


def outputs(tmp_path, numerics):
    """StageOutputs of a baseline and a gaze run (float32 config.json each) with the recorded `numerics`."""
    files = {}
    for run in RUNS:
        folder = tmp_path / "train" / f"{run.arm}_s0"
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "config.json").write_text(json.dumps({"mixed_precision": "no"}))
        (folder / "metrics.jsonl").write_text(json.dumps({"step": 10, "loss/action": 0.5}) + "\n")
        files[run] = folder / "metrics.jsonl"
    episodes = [
        {"arm": str(run), "task": "reach-v3", "condition": "clean", "seed": 1000 + i, "success": i % 2 == 0}
        for run in RUNS
        for i in range(4)
    ]
    return StageOutputs(
        episodes, [], {"episodes": 3, "frames": 30}, None, {r: {} for r in RUNS}, files,
        {r: {"kl": 1.0} for r in RUNS}, "figures/attention.png", "today", {"train": 1.0}, numerics,
    )  # fmt: skip


def report_of(tmp_path, numerics):
    spec = ReportSpec(
        "unit", ("reach-v3",), ("baseline", "gaze"), (0,), 10, 4, 0.1, (-1,), 4, ("clean",), 1000, 2, 0.5, {}
    )
    return build_report(spec, outputs(tmp_path, numerics), tmp_path)


def test_a_report_over_runs_with_one_recorded_key_names_it_not_the_report_machine(
    tmp_path, report_machine_is_amd
):
    assert NumericsKey.here("no") == AMD  # the report's own machine
    report = report_of(tmp_path, {RUNS[0]: on(INTEL), RUNS[1]: on(INTEL, INTEL)})
    machine = report["machine"]
    assert machine["numerics"] == INTEL.to_dict() and machine["precision"] == "no"
    assert machine["cpu_model"] == "AMD EPYC 7B13"  # the report machine's facts stay as they are
    said = f"float32 training on GenuineIntel ({XEON}), torch CPU capability AVX512, no bf16 instructions"
    assert numerics_text(machine) == said
    block = results_block(report, "figures/f.png")
    assert f"; {said}. Tasks: reach-v3;" in block.splitlines()[0]
    data = BlockData.read(block)
    assert data.numerics == INTEL and data.machines == ()
    assert '"machines"' not in block  # the data line of one key is the one made before the record


def test_runs_on_two_machines_give_a_several_machines_report(tmp_path, report_machine_is_amd):
    for numerics in ({RUNS[0]: on(INTEL), RUNS[1]: on(AMD)}, {RUNS[0]: on(INTEL), RUNS[1]: on(INTEL, AMD)}):
        machine = report_of(tmp_path, numerics)["machine"]
        assert machine["numerics"] is None and machine["precision"] is None
        assert [e["numerics"] for e in machine["trained_on"]] == [INTEL.to_dict(), AMD.to_dict()]
        said = numerics_text(machine)
        assert said.startswith(f"trained on several machines: float32 training on GenuineIntel ({XEON}), ")
        assert "AVX512, no bf16 instructions (runs baseline@s0" in said
        assert (
            "float32 training on AuthenticAMD, torch CPU capability AVX2, no bf16 instructions (runs " in said
        )
    assert machine["trained_on"][0]["runs"] == ["baseline@s0", "gaze@s0"]  # gaze's first attempt too
    assert machine["trained_on"][1]["runs"] == ["gaze@s0"]


def test_old_runs_without_a_record_keep_the_report_machines_key(tmp_path, report_machine_is_amd):
    precisions = {"baseline@s0": "no", "gaze@s0": "no"}
    assert machine_summary(precisions, {r: None for r in precisions}) == machine_summary(precisions)
    machine = report_of(tmp_path, {RUNS[0]: None, RUNS[1]: None})["machine"]
    assert machine["numerics"] == AMD.to_dict() and "trained_on" not in machine
    assert report_of(tmp_path, {})["machine"] == machine  # StageOutputs made without numerics
    # some runs recorded, some not: no one key, and the text says which runs it does not know
    partial = machine_summary(precisions, {"baseline@s0": on(INTEL), "gaze@s0": None})
    assert partial["numerics"] is None and partial["unrecorded_runs"] == ["gaze@s0"]
    assert numerics_text(partial).startswith("numerics recorded by some runs only: float32 training on Genu")
    assert numerics_text(partial).endswith("(runs baseline@s0); not recorded for (part of) gaze@s0")
    resumed_old = machine_summary(precisions, {"baseline@s0": on(INTEL), "gaze@s0": on(None, INTEL)})
    assert resumed_old["numerics"] is None and resumed_old["unrecorded_runs"] == ["gaze@s0"]


def test_the_finished_run_reader_the_archive_and_the_pool_carry_the_records(tmp_path):
    source = tmp_path / "exp"
    (source / "figures").mkdir(parents=True)
    imsave(source / "figures" / "attention.png", np.zeros((2, 2, 3)))  # the pool stacks the folders' figures
    record_numerics(source / "train" / "gaze_s0", "no", 0)
    for run in RUNS:
        (source / "train" / f"{run.arm}_s0" / "metrics.jsonl").parent.mkdir(parents=True, exist_ok=True)
        (source / "train" / f"{run.arm}_s0" / "metrics.jsonl").write_text("")
    stages = {"train": {"runs": {str(r): {"checkpoint": "x"} for r in RUNS}}}
    numerics = FinishedRun(source, {}, stages).numerics
    assert numerics[RUNS[0]] is None and numerics[RUNS[1]][0].key == NumericsKey.here("no")
    plain, _ = archived_files(source, RUNS)
    assert Path("train/gaze_s0") / NUMERICS_FILE in plain
    assert Path("train/baseline_s0") / NUMERICS_FILE not in plain  # a run made before the record has none
    a = outputs(tmp_path / "a", {RUNS[0]: on(INTEL)})
    b = outputs(tmp_path / "b", {RUNS[1]: None})
    merged = merge_outputs([source, source], [a, b], tmp_path / "pooled")
    assert merged.numerics == {RUNS[0]: on(INTEL), RUNS[1]: None}


def run_folder(tmp_path, name, machine):
    """A run folder whose report.json is the golden smoke report with `machine` as its machine record."""
    report = json.loads((GOLDEN / "smoke_report.json").read_text())
    report["machine"] = machine
    run = tmp_path / name
    (run / "figures").mkdir(parents=True)
    (run / report["figures"]["attention"]).write_bytes(b"png")
    (run / "report.json").write_text(json.dumps(report))
    return run


def test_check_compares_a_several_machines_run_by_agreement(script, tmp_path, capsys):
    repo = tmp_path / "repo"
    (repo / "docs").mkdir(parents=True)
    (repo / "docs" / "main-job.md").write_text("<!-- demo-results:start -->\n<!-- demo-results:end -->\n")
    precisions = {"baseline@s0": "no", "gaze@s0": "no"}
    one = machine_summary(precisions, {"baseline@s0": on(INTEL), "gaze@s0": on(INTEL)})
    assert script.main([str(run_folder(tmp_path, "page", one)), "--root", str(repo)]) == 0
    two = machine_summary(precisions, {"baseline@s0": on(INTEL), "gaze@s0": on(INTEL, AMD)})
    capsys.readouterr()
    assert script.main([str(run_folder(tmp_path, "mixed", two)), "--root", str(repo), "--check"]) == 0
    out = capsys.readouterr().out
    assert "the run trained on several machines (float32 training on GenuineIntel, torch CPU" in out
    assert "not an exact comparison but a test of agreement" in out
    assert "agrees with docs/main-job.md block 'demo-results' (not identical: different numerics)" in out
    assert BlockData.read((repo / "docs" / "main-job.md").read_text()).numerics == INTEL


def test_a_committed_archive_made_before_the_record_has_none():
    run = read_run(ROOT / "docs" / "records" / "paper-abl-b")
    assert run.numerics == {r: None for r in run.runs} and run.stage_outputs().numerics == run.numerics
