"""Issue 33: every report names the machine's numerics (the training precision the runs resolved, torch's CPU
capability, the bf16 instruction sets, the CPU) in report.json's "machine" and in the lines that say where it ran
(report.md's header, the results block's run line)."""

import json
from pathlib import Path

import torch

from gazereg.report import machine_summary, markdown, results_block
from gazereg.report.build import trained_precisions
from gazereg.report.ids import RunId
from gazereg.report.sections import numerics_text
from gazereg.runtime import hardware
from gazereg.runtime.hardware import NumericsKey

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = Path(__file__).parent / "report_golden"


def _runs(tmp_path, precisions):
    """{RunId: its metrics.jsonl} for runs whose folders hold a trainer's config.json with each precision (None:
    no config.json, as in an archive)."""
    files = {}
    for name, precision in precisions.items():
        folder = tmp_path / "train" / name.replace("@", "_")
        folder.mkdir(parents=True)
        if precision is not None:
            (folder / "config.json").write_text(json.dumps({"mixed_precision": precision, "steps": 3}))
        files[RunId.parse(name)] = folder / "metrics.jsonl"
    return files


def test_the_runs_precision_is_read_from_the_config_each_trainer_saved(tmp_path):
    files = _runs(tmp_path, {"gaze@s0": "no", "baseline@s0": "no", "glc@s0": None})
    assert trained_precisions(files) == {"baseline@s0": "no", "gaze@s0": "no", "glc@s0": None}


def test_the_machine_record_holds_the_key_when_the_runs_agree_on_a_precision():
    rec = machine_summary({"baseline@s0": "bf16", "gaze@s0": "bf16"})
    assert rec["precision"] == "bf16" and rec["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert rec["numerics"] == NumericsKey.here("bf16").to_dict()
    assert rec["bf16_isa"] == sorted(hardware.cpu_flags() & hardware.BF16_CPU_FLAGS)
    assert rec["cpu_model"] == hardware.cpu_identity()[1]
    assert numerics_text(rec).startswith("bf16 mixed precision training on ")
    assert f"torch CPU capability {rec['cpu_capability']}" in numerics_text(rec)
    for runs in ({"baseline@s0": "bf16", "gaze@s0": "no"}, {"baseline@s0": None}, None):
        rec = machine_summary(runs)
        assert rec["precision"] is None and rec["numerics"] is None
    assert numerics_text(machine_summary({"a@s0": "bf16", "b@s0": "no"})).startswith(
        "training precision differs between runs (bf16 mixed precision, float32); this report was made on a "
        "CPU with torch capability "
    )
    # a report pooled from archives: the CPU named is said to be the report's, not the training's
    said = numerics_text(machine_summary())
    assert said.startswith(
        "training precision not recorded; this report was made on a CPU with torch capability "
    )
    assert said.endswith("which need not be the one that trained")
    assert numerics_text({"summary": "an old report"}) == "numerics not recorded"


def test_report_md_and_the_block_run_line_name_the_numerics():
    report = json.loads((GOLDEN / "smoke_report.json").read_text())
    key = NumericsKey("no", "AVX2", (), "AuthenticAMD", "2.13.0+cpu")
    report["machine"].update(
        cpu_model="AMD EPYC 7B13", cpu_capability="AVX2", bf16_isa=[], numerics=key.to_dict()
    )
    said = "float32 training on AuthenticAMD (AMD EPYC 7B13), torch CPU capability AVX2, no bf16 instructions"
    assert f"Python 3.11.7; {said}; wall time 0.3 min." in markdown(report).splitlines()[2]
    run_line = results_block(report, "figures/f.png").splitlines()[0]
    assert f"(`gazereg experiment --preset smoke`); {said}. Tasks: reach-v3;" in run_line


def test_every_benchmark_records_the_cpu_capability_and_the_precision(load_script):
    timing = load_script("benchmarks/_timing.py")
    info = timing.machine_info(threads=3)
    assert info["resolved_precision"] == hardware.auto_precision("cpu") and info["threads"] == 3
    assert info["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert info["numerics"] == NumericsKey.here(info["resolved_precision"]).to_dict()
    assert timing.machine_info(precision="no")["numerics"]["precision"] == "no"
    benches = sorted((ROOT / "benchmarks").glob("bench_*.py"))
    assert len(benches) >= 10
    for bench in benches:  # each one's JSON names the machine: through _timing, or its own record of both
        text = bench.read_text()
        assert (
            "from _timing import" in text
            and "machine_info(" in text
            or ("get_cpu_capability()" in text and "dtype" in text)
        ), bench.name
