"""ResumableClock: a stage's time over every attempt, a killed one included."""

import json
import time

import pytest

from gazereg.runtime.clock import ResumableClock


def _saved(path):
    return json.loads(path.read_text())["seconds"]


def test_clock_carries_the_time_of_a_killed_attempt(tmp_path):
    path = tmp_path / "stages" / "train.clock.json"
    killed = ResumableClock(path, every=0.01).__enter__()
    deadline = time.monotonic() + 10
    while _saved(path) < 0.05 and time.monotonic() < deadline:  # wait for the ticker to save some time
        time.sleep(0.01)
    killed._stop.set()  # a kill: no __exit__, only what the ticker wrote survives
    killed._thread.join()
    before = _saved(path)
    assert before >= 0.05

    with ResumableClock(path, every=0.01) as clock:
        assert clock.before == before
        time.sleep(0.05)
    assert clock.seconds >= before + 0.05
    assert _saved(path) == clock.seconds  # the final save on a clean exit
    clock.clear()
    assert not path.exists()
    assert ResumableClock(path).seconds == 0.0  # cleared: a new job starts from zero


def test_clock_rejects_a_non_positive_interval(tmp_path):
    with pytest.raises(ValueError, match="every must be > 0"):
        ResumableClock(tmp_path / "c.json", every=0)
