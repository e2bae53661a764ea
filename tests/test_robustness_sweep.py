"""scripts/robustness_sweep.py: finished experiments' final checkpoints under more perturbations, the
conditions they already evaluated read from their own records."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from gazereg.runtime.errors import UsageError

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "robustness_sweep.py"


@pytest.fixture(scope="module")
def sweep(load_script):
    """scripts/robustness_sweep.py loaded as a module."""
    return load_script("scripts/robustness_sweep.py")


def rec(arm, condition, seed, success, task="t"):
    return dict(arm=arm, task=task, condition=condition, seed=seed, success=success)


def info(checkpoints, conditions=("clean", "dim:0.7"), records=(), **changes):
    base = dict(
        tasks=("t",), env="metaworld", episodes=2, seed_start=1000, max_steps=20, workers=1, batch=None
    )
    return {
        **base,
        "conditions": list(conditions),
        "checkpoints": checkpoints,
        "records": list(records),
        **changes,
    }


def test_plan_rolls_out_what_not_every_folder_evaluated_and_reuses_the_rest(sweep):
    a = info(
        {"gaze@s0": "x"}, records=[rec("gaze@s0", "clean", 1000, True), rec("gaze@s0", "dim:0.7", 1000, 0)]
    )
    b = info({"baseline@s0": "y"}, ("clean",), [rec("baseline@s0", "clean", 1000, False)])
    rollout, reused = sweep.plan({Path("a"): a, Path("b"): b}, ("clean", "dim:0.7", "tint:1"))
    assert rollout == ("dim:0.7", "tint:1")  # b never ran dim: both roll it out again, a's record dropped
    assert [(r["arm"], r["condition"]) for r in reused] == [("gaze@s0", "clean"), ("baseline@s0", "clean")]


@pytest.mark.parametrize(
    "b, message",
    [
        (info({"baseline@s0": "y"}, episodes=3), "b has episodes 3 but a has 2"),
        (info({"gaze@s0": "y"}), "run gaze@s0 is in both a and b"),
    ],
)
def test_plan_refuses_folders_whose_episodes_would_not_pair(sweep, b, message):
    with pytest.raises(UsageError, match=message):
        sweep.plan({Path("a"): info({"gaze@s0": "x"}), Path("b"): b}, ("clean",))


def test_comparisons_pair_each_arm_with_the_baseline_and_the_gaze_arm_with_its_controls(sweep):
    records = []
    for s in (0, 1):
        for seed in range(4):
            records += [
                rec(f"baseline@s{s}", "clean", seed, seed < 1),
                rec(f"gaze@s{s}", "clean", seed, seed < 3),
            ]
            records.append(rec(f"uniform@s{s}", "clean", seed, seed < 2))
    paired, seeds = sweep.comparisons(records)
    assert set(paired) == {
        "gaze vs baseline | clean",
        "uniform vs baseline | clean",
        "gaze vs uniform | clean",
    }
    assert paired["gaze vs baseline | clean"]["rate_diff"] == pytest.approx(0.5)
    assert paired["gaze vs uniform | clean"]["rate_diff"] == pytest.approx(0.25)
    assert seeds["gaze vs uniform | clean"]["above"] == 2
    result = {"conditions": ["clean", "dim:0.7"], "paired": paired, "seed_level": seeds}
    lines = sweep.difference_lines(result)
    assert lines[0] == "| condition | gaze vs baseline | uniform vs baseline | gaze vs uniform |"
    assert lines[2].startswith("| clean | +0.50 [") and ", seeds 2/0 |" in lines[2]
    assert lines[3] == "| dim:0.7 | - | - | - |"


@pytest.mark.sim
def test_the_sweep_rolls_out_the_new_condition_and_reads_clean_from_the_experiment(
    finished_experiment, tmp_path
):
    out = finished_experiment
    sweep = tmp_path / "sweep"
    args = [sys.executable, str(SCRIPT), str(out), "--conditions", "clean", "dim:0.7", "--out", str(sweep)]
    subprocess.run(args, check=True, cwd=out.parent, capture_output=True)
    result = json.loads((sweep / "robustness.json").read_text())
    report = json.loads((out / "report.json").read_text())
    assert result["rolled_out"] == ["dim:0.7"] and list(result["success"]) == ["baseline", "gaze"]
    for arm in ("baseline", "gaze"):
        assert result["success"][arm]["clean"] == report["success"][arm]["clean"]
        assert result["success"][arm]["dim:0.7"]["n"] == 3
    rolled = json.loads((sweep / "eval" / "eval_info.json").read_text())["episodes"]
    assert {r["condition"] for r in rolled} == {"dim:0.7"} and len(rolled) == 6
    assert "| dim:0.7 | " in (sweep / "robustness.md").read_text()
    bad = subprocess.run(
        [*args[:3], "--conditions", "dim:0.7", "--out", str(sweep)], capture_output=True, text=True
    )
    assert bad.returncode == 2 and "must include clean" in bad.stderr


ARCHIVES = [ROOT / "docs" / "records" / name for name in ("paper-abl-b", "paper-abl-c")]


def test_the_sweep_reads_archives_when_every_condition_is_in_their_records(sweep, tmp_path, capsys):
    """Committed archives (evaluation records compressed, no checkpoints): conditions both evaluated are read,
    none rolled out; a condition that would need a rollout is refused in one line, before any work."""
    out = tmp_path / "sweep"
    args = [*map(str, ARCHIVES), "--conditions", "clean", "dim:0.7", "--out", str(out)]
    assert sweep.main(args) == 0
    result = json.loads((out / "robustness.json").read_text())
    assert result["rolled_out"] == [] and list(result["success"]) == ["baseline", "gaze"]
    for archive, arm in zip(ARCHIVES, ("baseline", "gaze")):
        report = json.loads((archive / "report.json").read_text())
        for condition in ("clean", "dim:0.7"):
            mine, theirs = result["success"][arm][condition], report["success"][arm][condition]
            assert (mine["successes"], mine["n"]) == (theirs["successes"], theirs["n"]) and mine["n"] == 300
    assert "gaze vs baseline | dim:0.7" in result["paired"]
    assert not (out / "eval").exists()
    with pytest.raises(
        UsageError, match=r"tint:1 must be rolled out, but .*paper-abl-b.* keep no checkpoints"
    ):
        sweep.main([*args[:2], "--conditions", "clean", "tint:1", "--out", str(tmp_path / "other")])
    assert not (tmp_path / "other").exists()
