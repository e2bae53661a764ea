import subprocess
import sys

from gazereg.cli import main
from gazereg.runtime.config import split_preset


def test_help_lists_available_commands(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert "usage: gazereg" in out


def test_unknown_command_is_an_error(capsys):
    assert main(["frobnicate"]) == 2
    assert "unknown command 'frobnicate'" in capsys.readouterr().err


def test_split_preset():
    assert split_preset(["--preset", "quick", "--a.b=1"], "smoke") == ("quick", ["--a.b=1"])
    assert split_preset(["--preset=paper"], "smoke") == ("paper", [])
    assert split_preset([], "smoke") == ("smoke", [])


def test_console_script_runs():
    r = subprocess.run(
        [sys.executable, "-m", "gazereg.cli", "--help"], capture_output=True, text=True, check=True
    )
    assert "commands:" in r.stdout
