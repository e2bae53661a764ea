"""Run identities: one text form on disk, parsed in one place; the convergence tally reads them."""

import pytest

from gazereg.report.convergence import ConvergencePoint, checkpoint_tally
from gazereg.report.ids import RunId
from gazereg.report.tables import per_seed_table, run_of


def test_run_names_round_trip_in_the_on_disk_form():
    assert str(RunId("gaze", 0)) == "gaze@s0"
    assert str(RunId("other_episode", 12, 600)) == "other_episode@s12#600"
    for text in ("gaze@s0", "baseline@s2#1000", "other_episode@s12#600"):
        assert str(RunId.parse(text)) == text
    assert RunId.parse("gaze@s1#600") == RunId("gaze", 1, 600) == RunId("gaze", 1).at_step(600)
    assert RunId("gaze", 1, 600).at_step(None) == RunId("gaze", 1)
    assert run_of({"arm": "perturbed@s3"}).arm == "perturbed"


@pytest.mark.parametrize("text", ["gaze", "gaze@0", "gaze@s", "gaze@s1#", "gaze@s1#x", "@s1", "a@b@s1"])
def test_malformed_run_names_are_errors_that_say_so(text):
    with pytest.raises(ValueError, match="is not a run name"):
        RunId.parse(text)


def test_arm_names_cannot_hold_the_separators():
    with pytest.raises(ValueError, match="without '@' or '#'"):
        RunId("ga@ze", 0)
    with pytest.raises(ValueError, match=">= 0"):
        RunId("gaze", -1)


def test_checkpoint_tally_pools_seeds_per_arm_and_step():
    points = [
        ConvergencePoint(RunId("gaze", 0, 5), "reach-v3", 1000, True),
        ConvergencePoint(RunId("gaze", 1, 5), "reach-v3", 1000, False),
        ConvergencePoint(RunId("baseline", 0, 5), "reach-v3", 1000, False),
        ConvergencePoint(RunId("gaze", 0, 10), "reach-v3", 1000, True),
    ]
    assert checkpoint_tally(points) == {"gaze": {5: (1, 2), 10: (1, 1)}, "baseline": {5: (0, 1)}}
    with pytest.raises(ValueError, match="names no training step"):
        checkpoint_tally([ConvergencePoint(RunId("gaze", 0), "reach-v3", 1000, True)])


def test_per_seed_table_keeps_the_run_names():
    recs = [
        {"arm": a, "condition": "clean", "success": s} for a, s in [("b@s1", 1), ("a@s0", 0), ("b@s1", 0)]
    ]
    assert per_seed_table(recs) == {"a@s0": {"clean": [0, 1]}, "b@s1": {"clean": [1, 2]}}
