"""scripts/horizon.py: a longer evaluation of a finished experiment, and its short-limit outcomes equal to the
experiment's own evaluation."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).parents[1] / "scripts" / "horizon.py"


@pytest.mark.sim
def test_horizon_counts_successes_within_both_limits_and_reproduces_the_short_one(finished_experiment):
    out = finished_experiment
    subprocess.run([sys.executable, str(SCRIPT), str(out), "--max-steps", "40"], check=True, cwd=out.parent)
    result = json.loads((out / "horizon40" / "horizon.json").read_text())
    report = json.loads((out / "report.json").read_text())
    assert result["short_steps"] == 15 and set(result["arms"]) == {"baseline", "gaze"}
    for arm, t in result["arms"].items():
        assert t["episodes"] == 3 and t["mismatches"] == 0
        assert t["within_short"] == report["success"][arm]["clean"]["successes"]
        assert t["within_long"] == t["within_short"] + t["only_long"]
    assert "| baseline | 3 |" in (out / "horizon40" / "horizon.md").read_text()
    bad = subprocess.run(
        [sys.executable, str(SCRIPT), str(out), "--max-steps", "15"], capture_output=True, text=True
    )
    assert (
        bad.returncode == 2
        and "horizon: error: --max-steps 15 is not longer than the experiment's 15" in bad.stderr
    )


def test_tally_splits_successes_by_the_short_limit_and_counts_outcomes_that_differ():
    sys.path.insert(0, str(SCRIPT.parent))
    from horizon import tally

    def rec(seed, success, length, arm="gaze@s0"):
        return dict(arm=arm, task="t", seed=seed, condition="clean", success=success, length=length)

    # (seed, success, length) with a 500-step limit and with the experiment's 20
    long = [rec(*x) for x in ((0, True, 10), (1, True, 90), (2, False, 120), (3, True, 12))]
    short = [rec(s, False, 20) for s in (1, 2, 3)] + [rec(0, True, 10)]
    long.append(rec(0, True, 5, "baseline@s1"))
    short.append(rec(0, True, 5, "baseline@s1"))
    t = tally(long, short, limit=20)
    assert t["gaze"] == dict(episodes=4, within_short=2, within_long=3, only_long=1, mismatches=1)  # seed 3
    assert t["baseline"] == dict(episodes=1, within_short=1, within_long=1, only_long=0, mismatches=0)


ARCHIVE = Path(__file__).parents[1] / "docs" / "records" / "paper-abl-b"


def test_horizon_reads_an_archive_and_refuses_to_roll_it_out_in_one_line(capsys):
    """A committed archive holds only eval_info.json.gz and no checkpoints: the experiment's own clean
    outcomes and step limit are read from it; the long evaluation is refused (one line, exit 2)."""
    sys.path.insert(0, str(SCRIPT.parent))
    import horizon

    from gazereg.experiment import read_run
    from gazereg.runtime.errors import UsageError, report_errors

    run = read_run(ARCHIVE)
    clean = [r for r in run.episodes() if r["condition"] == "clean"]
    t = horizon.tally(clean, run.episodes(), run.max_steps)  # the experiment against itself
    report = run.report["success"]["baseline"]["clean"]
    assert t["baseline"]["episodes"] == report["n"] == 300 and t["baseline"]["mismatches"] == 0
    assert t["baseline"]["within_short"] == t["baseline"]["within_long"] == report["successes"]
    with pytest.raises(UsageError, match="not longer than the experiment's 120"):
        horizon.long_eval_config(run, 100)
    assert report_errors("horizon", horizon.main, [str(ARCHIVE)], verbose=False) == 2
    err = capsys.readouterr().err
    assert "paper-abl-b is an archive" in err and "no checkpoints" in err and len(err.splitlines()) == 1
    assert not (ARCHIVE / "horizon500").exists()


EXPERT_SCRIPT = Path(__file__).parents[1] / "scripts" / "expert_horizon.py"


@pytest.mark.sim
def test_expert_horizon_counts_the_experts_steps_on_the_evaluation_setups(tmp_path):
    md = tmp_path / "expert.md"
    args = [sys.executable, str(EXPERT_SCRIPT), "--preset", "quick", "--episodes", "2", "--max-steps", "200"]
    r = subprocess.run([*args, "--out", str(md)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    rows = {line.split(" | ")[0].strip("| "): line.split(" | ") for line in md.read_text().splitlines()}
    for task in ("reach-v3", "button-press-topdown-v3"):  # the quick preset's tasks, solved by their experts
        cells = rows[task]
        assert (
            cells[1] == "2" and cells[2] == "2" and cells[3] == "2" and 0 < int(cells[5].strip(" |")) <= 120
        )
    assert "seeds 1000..1001" in md.read_text() and r.stdout == md.read_text()
    bad = subprocess.run([*args[:-2], "--max-steps", "10"], capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "--max-steps >= the preset's" in bad.stderr
