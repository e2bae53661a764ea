"""scripts/power.py: McNemar power from a run's own paired episodes (`--run`), or from counts."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from gazereg.evaluation.stats import pairs_for_power, pairs_for_power_normal

STUDY = "docs/records/study10-s0"


@pytest.fixture(scope="module")
def power(load_script):
    return load_script("scripts/power.py", "power_script")


def test_the_runs_counts_are_its_reports_paired_table(power):
    table = json.loads(Path(STUDY, "report.json").read_text())["paired"]["gaze vs baseline | clean"]
    assert power.measured_pairs([STUDY], "gaze", "baseline", "clean", None) == (
        table["gaze_only"],
        table["baseline_only"],
        table["pairs"],
    )


def test_tasks_split_the_pairs(power):
    some = ["box-close-v3", "door-unlock-v3"]
    rest = ["bin-picking-v3", "door-lock-v3", "hand-insert-v3"]
    a, b = (power.measured_pairs([STUDY], "gaze", "baseline", "clean", t) for t in (some, rest))
    whole = power.measured_pairs([STUDY], "gaze", "baseline", "clean", None)
    assert tuple(x + y for x, y in zip(a, b)) == whole and a[2] == 100


def test_it_prints_the_rates_and_the_power(power, capsys):
    assert power.main(["--run", STUDY, "--tasks", "box-close-v3", "--show", "50"]) == 0
    out = capsys.readouterr().out
    assert f"in {STUDY} on box-close-v3" in out and "of 50)" in out and "  50 pairs: power" in out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--run", STUDY, "--pairs", "10"], "not both"),
        (["--a-only", "3"], "give --a-only, --b-only and --pairs, or --run"),
        (["--run", STUDY, "--tasks", "reach-v3"], "are not tasks of"),
        (["--run", STUDY, "--arm", "glc"], "no episodes of glc paired with baseline"),
        (["--a-only", "0", "--b-only", "0", "--pairs", "10"], "no discordant pairs"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(power, capsys, argv, message):
    with pytest.raises(SystemExit) as e:
        power.main(argv)
    assert e.value.code == 2 and message in capsys.readouterr().err


def test_the_normal_approximation_is_near_the_exact_count():
    exact = pairs_for_power(63 / 300, 15 / 300)
    assert abs(pairs_for_power_normal(63 / 300, 15 / 300) - exact) < 0.15 * exact
    assert pairs_for_power_normal(0.1, 0.1) == math.inf
    with pytest.raises(ValueError):
        pairs_for_power_normal(0.0, 0.0)
