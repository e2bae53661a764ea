"""SIGTERM ends a command with one line and exit 143 after it unwinds, and an experiment stage it interrupts
keeps the time it ran: a resumed run's stage time (the marker's `seconds`, the report's stage_times_s)
adds it (`gazereg.runtime.errors.sigterm_raises`, `gazereg.experiment.runner`)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from dataclasses import replace

import gazereg.experiment.runner as runner
from gazereg.experiment.config import smoke
from gazereg.experiment.runner import Experiment
from gazereg.runtime.errors import report_errors

# A real `gazereg experiment` whose preflight passes and whose first stage (demos) writes a file and then
# waits, standing in for a long collection; the test sends it SIGTERM there.
SLOW_DEMOS = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    import gazereg.experiment.cli as experiment_cli
    import gazereg.experiment.runner as runner
    from gazereg import cli

    def slow_demos(self, results):
        Path(sys.argv[1]).write_text("started")
        time.sleep(120)

    runner.Experiment.stage_demos = slow_demos
    experiment_cli.preflight = lambda cfg: None  # the test is about SIGTERM, not the simulator's tasks
    sys.exit(cli.main(["experiment", "--preset", "smoke", "--out", sys.argv[2]]))
    """
)


def test_sigterm_during_a_stage_prints_one_line_exits_143_and_the_resumed_run_counts_its_time(
    tmp_path, monkeypatch
):
    out, started = tmp_path / "exp", tmp_path / "started"
    env = {k: v for k, v in os.environ.items() if k != "GAZEREG_DEBUG"}
    proc = subprocess.Popen(
        [sys.executable, "-c", SLOW_DEMOS, str(started), str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        deadline = time.monotonic() + 60
        while not started.exists():
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the demos stage did not start within 60 s"
            time.sleep(0.1)
        time.sleep(1.5)  # the stage runs 1.5 s before the signal
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 143, err
    assert err.splitlines()[-1] == (
        "gazereg experiment: terminated (SIGTERM) during stage demos; rerun the same command to resume"
    )
    assert "Traceback" not in err
    interrupted = json.loads((out / "stages" / "demos.clock.json").read_text())["seconds"]
    assert interrupted >= 1.5  # saved as the stage unwound, not at the clock's next 30 s tick

    # the same command again: every stage finishes at once here; demos counts the interrupted attempt
    for stage in runner.STAGES:
        monkeypatch.setattr(Experiment, f"stage_{stage}", lambda self, results: {})
    monkeypatch.setattr(runner, "preflight", lambda cfg: None)
    exp = Experiment(replace(smoke(), out=out), "smoke")
    exp.run()
    assert exp.times["demos"] >= interrupted
    assert json.loads((out / "stages" / "demos.json").read_text())["seconds"] == exp.times["demos"]
    assert not (out / "stages" / "demos.clock.json").exists()


def test_report_errors_turns_sigterm_into_one_line_and_exit_143_after_cleanup(capsys, monkeypatch):
    """In this process: the handler raises in the main thread, `finally` blocks run, the line names what was
    running when the code says (`annotate_interruption`), and the previous handler is back afterwards."""
    from gazereg.runtime.errors import annotate_interruption

    def guard(signum, frame):  # never let SIGTERM end pytest itself
        pass

    fallback = signal.signal(signal.SIGTERM, guard)
    try:
        cleaned = []

        def entry(argv):
            try:
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(5)
                return 0
            except BaseException as e:
                annotate_interruption(e, "step 3", "rerun to resume")
                raise
            finally:
                cleaned.append(True)

        assert report_errors("gazereg x", entry, [], verbose=False) == 143
        assert cleaned == [True]
        assert capsys.readouterr().err.splitlines() == [
            "gazereg x: terminated (SIGTERM) during step 3; rerun to resume"
        ]
        assert signal.getsignal(signal.SIGTERM) is guard
    finally:
        signal.signal(signal.SIGTERM, fallback)


def test_an_interrupted_stage_is_named_and_keeps_its_time(tmp_path, monkeypatch, capsys):
    """Ctrl-C as well: the stage is named, its time so far is saved for the resumed run."""

    def slow_demos(self, results):
        time.sleep(0.3)
        raise KeyboardInterrupt()

    monkeypatch.setattr(runner, "preflight", lambda cfg: None)
    monkeypatch.setattr(Experiment, "stage_demos", slow_demos)
    exp = Experiment(replace(smoke(), out=tmp_path / "exp"))
    assert report_errors("gazereg experiment", lambda argv: exp.run(), [], verbose=False) == 130
    assert capsys.readouterr().err.splitlines() == [
        "gazereg experiment: interrupted during stage demos; rerun the same command to resume"
    ]
    saved = json.loads((tmp_path / "exp" / "stages" / "demos.clock.json").read_text())["seconds"]
    assert saved >= 0.3
