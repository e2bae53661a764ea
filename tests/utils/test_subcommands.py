"""The shared subcommand dispatcher and the three commands built on it (`gazereg`, `gazereg import`, `viz`)."""

import sys

import pytest

from gazereg.runtime.subcommands import Subcommands, load_entry

SEEN: list[list[str]] = []


def record(argv):
    SEEN.append(argv)
    return None  # None counts as success


def fail(argv):
    return 3


TABLE = Subcommands(
    prog="tool",
    synopsis="<thing> [options]",
    commands={
        "record": (f"{__name__}:record", "record the arguments"),
        "fail": (f"{__name__}:fail", "exit with status 3"),
        "absent": ("no_such_package.module:main", "never offered"),
    },
    heading="things:",
    footer="More text.",
    noun="thing",
)


def test_usage_lists_installed_commands_in_a_column():
    assert TABLE.usage() == "\n".join(
        [
            "usage: tool <thing> [options]",
            "",
            "things:",
            "  record  record the arguments",
            "  fail    exit with status 3",
            "",
            "More text.",
        ]
    )
    assert list(TABLE.available()) == ["record", "fail"]


@pytest.mark.parametrize("argv", [[], ["-h"], ["--help"]])
def test_help(argv, capsys):
    assert TABLE.main(argv) == 0
    assert capsys.readouterr().out.startswith("usage: tool <thing>")


def test_dispatch_passes_the_rest_and_returns_the_status():
    SEEN.clear()
    assert TABLE.main(["record", "--a", "1"]) == 0
    assert SEEN == [["--a", "1"]]
    assert TABLE.main(["fail"]) == 3


@pytest.mark.parametrize("name", ["nope", "absent"])
def test_unknown_or_not_installed_is_an_error(name, capsys):
    assert TABLE.main([name]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"tool: unknown thing {name!r}\n\nusage: tool")


def test_runner_wraps_the_call():
    calls = []

    def run(name, entry, argv):
        calls.append(name)
        return entry(argv) or 7

    assert TABLE.main(["record"], run=run) == 7 and calls == ["record"]


def test_argv_defaults_to_sys_argv(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["tool", "--help"])
    assert TABLE.main() == 0
    assert "things:" in capsys.readouterr().out


def test_tables_of_the_gazereg_commands_name_real_functions():
    from gazereg.cli import COMMANDS as top
    from gazereg.cli import GLC as glc
    from gazereg.data.cli import COMMANDS as imports
    from gazereg.viz.cli import COMMANDS as viz

    # every top-level command is a module's main, or a table of gazereg.cli's own (`gazereg glc`, whose entries
    # live in two layers); not imported here: they load torch and the simulators
    assert all(t.endswith(":main") or t.startswith("gazereg.cli:") for t, _ in top.commands.values())
    assert top.commands["glc"][0] == "gazereg.cli:glc_main" and callable(load_entry("gazereg.cli:glc_main"))
    for table in (imports, viz, glc):
        for target, _ in table.available().values():
            assert callable(load_entry(target)), target


def test_gazereg_import_and_viz_usage(capsys):
    from gazereg.data import cli as data_cli
    from gazereg.viz import cli as viz

    assert viz.main(["--help"]) == 0
    assert capsys.readouterr().out == (
        "usage: gazereg viz <figure> [options]\n\nfigures:\n"
        "  strip    frames of an episode with its gaze heatmap and point\n"
    )
    assert viz.main(["nope"]) == 2
    assert "gazereg viz: unknown figure 'nope'" in capsys.readouterr().err
    assert data_cli.main([]) == 0
    out = capsys.readouterr().out
    assert out.startswith(
        "usage: gazereg import <lerobot|hdf5|export-priors|write-gaze> [options]\n\n  lerobot "
    )
    assert "gazereg import export-priors --store STORE" in out
    assert data_cli.main(["nope"]) == 2
    assert "gazereg import: unknown source 'nope'" in capsys.readouterr().err
