import subprocess
import sys
from dataclasses import dataclass

import pytest

from gazereg.cli import main
from gazereg.runtime.config import parse_named, split_preset
from gazereg.runtime.errors import UsageError


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


@dataclass
class _Size:
    width: int = 1


_SIZES = {"one": _Size, "two": lambda: _Size(width=2)}


def test_parse_named_returns_the_preset_it_chose_with_the_config():
    with pytest.raises(UsageError, match="--preset NAME is required"):  # the registry's order never chooses
        parse_named(_SIZES, ["--width", "5"], prog="t")
    assert parse_named({"one": _Size}, ["--width", "5"], prog="t") == (
        "one",
        _Size(width=5),
    )  # its own default
    assert parse_named(_SIZES, [], prog="t", default="two") == ("two", _Size(width=2))
    assert parse_named(_SIZES, ["--preset", "two"], prog="t", required=True) == ("two", _Size(width=2))
    with pytest.raises(UsageError, match="--preset NAME is required"):
        parse_named(_SIZES, ["--width", "5"], prog="t", default="two", required=True)
    with pytest.raises(UsageError, match="unknown preset 'three'"):
        parse_named(_SIZES, ["--preset=three"], prog="t")


def test_help_without_the_preset_it_needs_names_the_presets(capsys):
    for argv in (["--help"], ["-h", "--width", "5"]):
        with pytest.raises(SystemExit) as stop:
            parse_named(_SIZES, argv, prog="t", description="what t does", required=True)
        assert stop.value.code == 0
        out = capsys.readouterr().out
        assert "what t does" in out and "Presets: one, two." in out and "usage: t --preset NAME" in out
    with pytest.raises(SystemExit) as stop:  # with the preset: tyro's help, its options and values
        parse_named(_SIZES, ["--preset", "two", "--help"], prog="t", required=True)
    assert stop.value.code == 0 and "--width" in capsys.readouterr().out


def test_console_script_runs():
    r = subprocess.run(
        [sys.executable, "-m", "gazereg.cli", "--help"], capture_output=True, text=True, check=True
    )
    assert "commands:" in r.stdout
