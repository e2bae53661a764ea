"""gazereg.runtime.progress: one redrawn line on a terminal, a line a tenth (or a minute) elsewhere, rate and ETA
from a fake clock."""

import io
import multiprocessing

import pytest

from gazereg.runtime import progress
from gazereg.runtime.progress import Progress, default_mode, format_duration, format_rate


@pytest.fixture(autouse=True)
def wide_terminal(monkeypatch):
    """Fake terminals 200 columns wide, whatever terminal runs the tests."""
    monkeypatch.setenv("COLUMNS", "200")


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


class Stream(io.StringIO):
    def __init__(self, tty: bool) -> None:
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


def test_durations_and_rates_read_as_words():
    assert [format_duration(s) for s in (0, 42.4, 60, 185, 3599, 3720, 7260)] == [
        "0 s",
        "42 s",
        "1 min 00 s",
        "3 min 05 s",
        "59 min 59 s",
        "1 h 02 min",
        "2 h 01 min",
    ]
    assert format_rate(2.1, "steps") == "2.1 steps/s"
    assert format_rate(0.35, "episodes") == "0.35 episodes/s"
    assert format_rate(123.4, "steps") == "123 steps/s"
    assert format_rate(0.005, "episodes") == "0.3 episodes/min"


def test_rate_and_eta_count_only_the_work_done_since_the_bar_was_made():
    clock, stream = Clock(), Stream(tty=False)
    bar = Progress("train baseline_s0", 5000, done=1000, stream=stream, clock=clock)
    assert bar.rate() is None and bar.eta_s() is None
    assert bar.text() == "train baseline_s0: 1000/5000 steps (20%)"
    clock.t += 100
    bar.update(200)  # 200 steps in 100 s: 2 steps/s, 3800 left
    assert bar.rate() == pytest.approx(2.0) and bar.eta_s() == pytest.approx(1900)
    bar.note(action="0.0412")
    assert bar.text() == "train baseline_s0: 1200/5000 steps (24%), 2 steps/s, ETA 31 min 40 s, action=0.0412"


def test_a_terminal_gets_one_line_redrawn_in_place_and_a_newline_at_the_end():
    clock, stream = Clock(), Stream(tty=True)
    with Progress("eval runs/x", 10, "episodes", stream=stream, clock=clock) as bar:
        assert bar.mode == "tty"
        for _ in range(10):
            clock.t += 0.125  # redrawn at once, then at most every 0.2 s (every other update), and the last
            bar.update()
    out = stream.getvalue()
    assert out.count("\n") == 1 and out.endswith("\n")
    draws = out.split("\r")[1:]
    assert [d.split(":")[1].split(" ")[1] for d in draws] == [
        "1/10",
        "3/10",
        "5/10",
        "7/10",
        "9/10",
        "10/10",
        "10/10",
    ]
    assert draws[0] == "eval runs/x: 1/10 episodes (10%), 8 episodes/s, ETA 1 s" + progress.CLEAR_TO_END
    end = "eval runs/x: 10/10 episodes (100%), 8 episodes/s, took 1 s" + progress.CLEAR_TO_END + "\n"
    assert draws[-1] == end


def test_elsewhere_a_line_per_tenth_after_the_first_seconds_and_a_final_line():
    clock, stream = Clock(), Stream(tty=False)
    with Progress("train gaze_s0", 100, stream=stream, clock=clock) as bar:
        assert bar.mode == "lines"
        for _ in range(100):
            clock.t += 1.0
            bar.update()
    lines = stream.getvalue().splitlines()
    assert "\r" not in stream.getvalue()
    assert len(lines) == 10  # 10%, 20%, ... 90%, then the final line
    assert lines[0] == "train gaze_s0: 10/100 steps (10%), 1 steps/s, ETA 1 min 30 s"
    assert lines[-1] == "train gaze_s0: 100/100 steps (100%), 1 steps/s, took 1 min 40 s"


def test_slow_work_gets_a_line_a_minute_and_short_work_only_its_final_line():
    clock, stream = Clock(), Stream(tty=False)
    bar = Progress("collect d", 1000, "episodes", stream=stream, clock=clock)
    for _ in range(6):
        clock.t += 25.0
        bar.update()
    assert [line.split(":")[1].split(",")[0] for line in stream.getvalue().splitlines()] == [
        " 3/1000 episodes (0%)",  # 75 s: a minute after the start
        " 6/1000 episodes (0%)",  # 150 s: a minute after that line
    ]
    quick = Stream(tty=False)
    with Progress("priors p", 50, "episodes", stream=quick, clock=clock) as bar:
        for _ in range(50):
            clock.t += 0.05
            bar.update()
    assert quick.getvalue().splitlines() == ["priors p: 50/50 episodes (100%), 20 episodes/s, took 2 s"]


def test_nothing_is_written_when_disabled_or_when_nothing_was_left_to_do():
    clock = Clock()
    for kwargs in ({"enabled": False}, {"mode": "off"}):
        stream = Stream(tty=True)
        with Progress("x", 3, stream=stream, clock=clock, **kwargs) as bar:
            bar.update(3)
        assert stream.getvalue() == ""
    stream = Stream(tty=True)
    with Progress("x", 3, done=3, stream=stream, clock=clock):
        pass
    assert stream.getvalue() == ""


def test_a_failure_ends_the_terminal_line_without_saying_took():
    clock, stream = Clock(), Stream(tty=True)
    with pytest.raises(RuntimeError), Progress("x", 10, stream=stream, clock=clock) as bar:
        clock.t += 1
        bar.update(4)
        raise RuntimeError
    assert stream.getvalue().endswith(
        "x: 4/10 steps (40%), 4 steps/s, ETA 2 s" + progress.CLEAR_TO_END + "\n"
    )


def test_a_worker_process_writes_lines_even_on_a_terminal(monkeypatch):
    assert default_mode(Stream(tty=True)) == "tty" and default_mode(Stream(tty=False)) == "lines"
    monkeypatch.setattr(multiprocessing, "parent_process", lambda: object())  # as in a spawned pool worker
    assert default_mode(Stream(tty=True)) == "lines"


def test_the_terminal_line_is_cut_to_the_terminals_width(monkeypatch):
    monkeypatch.setenv("COLUMNS", "30")  # a stream without a terminal size of its own: the COLUMNS variable
    clock, stream = Clock(), Stream(tty=True)
    with Progress("train baseline_s0", 5000, stream=stream, clock=clock) as bar:
        clock.t += 1
        bar.update(10)
    cut = "train baseline_s0: 10/5000 st"  # 29 characters: the last column stays free
    assert stream.getvalue().split("\r")[1:] == [
        cut + progress.CLEAR_TO_END,
        cut + progress.CLEAR_TO_END + "\n",
    ]
