"""scripts/horizon.py: a longer evaluation of a finished experiment, and its short-limit outcomes equal to the
experiment's own evaluation."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.sim

SCRIPT = Path(__file__).parents[1] / "scripts" / "horizon.py"


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
    assert bad.returncode != 0 and "not longer than the experiment's 15" in bad.stderr


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


EXPERT_SCRIPT = Path(__file__).parents[1] / "scripts" / "expert_horizon.py"


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
