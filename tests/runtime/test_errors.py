import subprocess
import sys

import pytest

from gazereg import cli
from gazereg.runtime.errors import UsageError, exit_status, one_line, report_errors, split_verbose


def test_exit_status_tells_bad_usage_from_failure():
    assert exit_status(UsageError("--steps must be >= 1")) == 2
    assert exit_status(FileNotFoundError("no store")) == 2
    assert exit_status(RuntimeError("crashed")) == 1
    assert exit_status(FloatingPointError("non-finite loss")) == 1


def test_messages_are_one_line():
    assert one_line(UsageError("a\n  b")) == "a b"
    assert one_line(KeyError("unknown gaze source 'x'")) == "KeyError: unknown gaze source 'x'"
    assert one_line(RuntimeError("")) == "RuntimeError: RuntimeError"


def test_verbose_comes_from_the_flag_or_the_environment(monkeypatch):
    monkeypatch.delenv("GAZEREG_DEBUG", raising=False)
    assert split_verbose(["train", "--verbose", "--steps", "3"]) == (["train", "--steps", "3"], True)
    assert split_verbose(["train"]) == (["train"], False)
    monkeypatch.setenv("GAZEREG_DEBUG", "1")
    assert split_verbose(["train"]) == (["train"], True)


@pytest.mark.parametrize(("error", "status"), [(UsageError("bad --x"), 2), (RuntimeError("boom"), 1)])
def test_report_errors_prints_one_line_and_no_traceback(capsys, error, status):
    def entry(argv):
        raise error

    assert report_errors("gazereg x", entry, [], verbose=False) == status
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("gazereg x: error: ") and "Traceback" not in err
    assert report_errors("gazereg x", entry, [], verbose=True) == status
    assert "Traceback" in capsys.readouterr().err


def test_the_command_line_exits_2_with_one_line_for_a_missing_store(tmp_path):
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "gazereg.cli",
            "train",
            "--data.store",
            str(tmp_path / "none"),
            "--steps",
            "2",
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"gazereg train: error: {tmp_path / 'none'} is not an episode store (no store.json); create it first"
    ]


def test_in_process_main_maps_errors_too(tmp_path, capsys):
    assert cli.main(["train", "--data.store", str(tmp_path / "none")]) == 2
    assert "is not an episode store" in capsys.readouterr().err
