"""The `gazereg` command: a thin dispatcher over library entry points.

    gazereg COMMAND [--preset NAME] [--dotted.option value ...] [--verbose]

Each subcommand lives in its own module as `main(argv: list[str]) -> int` and is imported only when it runs,
so `gazereg --help` stays fast and heavy optional dependencies load only where they are needed.
"""

from __future__ import annotations

import sys

from gazereg.runtime.errors import report_errors, split_verbose
from gazereg.runtime.subcommands import Entry, Subcommands, run_entry_logged
from gazereg.runtime.version import __version__

# name -> ("module:function", one-line help). Only subcommands whose module is installed are offered.
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "collect": ("gazereg.envs.collect:main", "roll out scripted experts in simulation into an episode store"),
    "priors": (
        "gazereg.gaze.priors:main",
        "make per-frame gaze priors for an episode store from a gaze source",
    ),
    "train": ("gazereg.training.loop:main", "train a policy, with or without the gaze regularizer"),
    "eval": (
        "gazereg.evaluation.rollout:main",
        "evaluate a checkpoint in simulation (clean, lighting, sensor noise)",
    ),
    "experiment": (
        "gazereg.experiment:main",
        "the end-to-end pipeline: demos, priors, training, evaluation, report",
    ),
    "pretrain": ("gazereg.experiment.pretrain:main", "pretrain a generalist VLA on many tasks (ML45)"),
    "pool": (
        "gazereg.experiment.pool:main",
        "one report over run folders of one experiment that differ only in their training seeds and arms",
    ),
    "sittings": (
        "gazereg.experiment.sittings:main",
        "a benchmark too long for one session in archived sittings (run the next, list, pool)",
    ),
    "archive": (
        "gazereg.experiment.archive:main",
        "a finished experiment's results without its data or checkpoints, to commit; `pool` reads it",
    ),
    "compare": (
        "gazereg.experiment.compare:main",
        "compare two experiment runs on the setups both evaluated (paired tests per arm and condition)",
    ),
    "presets": ("gazereg.experiment.presets:main", "list every preset of every kind, one line each"),
    "glc": ("gazereg.cli:glc_main", "train / evaluate the GLC video gaze estimator"),
    "import": (
        "gazereg.data.cli:main",
        "import LeRobot v3 or HDF5 demonstrations into an episode store",
    ),
    "viz": ("gazereg.viz.cli:main", "draw episodes with their gaze and attention"),
}

GLC = Subcommands(
    prog="gazereg glc",
    synopsis="<train|eval> [--preset NAME] [options]",
    commands={
        "train": ("gazereg.training.glc_cli:main", "train / fine-tune GLC on an episode store's gaze"),
        "eval": (
            "gazereg.gaze.glc.cli:eval_main",
            "GLC metrics on held-out episodes vs centre-prior and uniform baselines",
        ),
    },
    footer=(
        "`train` (`gazereg.training.glc_cli`) learns from any episodes that carry per-frame gaze points and "
        "writes\n`<out>/final/`, a folder the `glc` gaze source loads (`--source-params checkpoint=<out>/final`)."
    ),
    noun="subcommand",
)
"""`gazereg glc`: its train entry lives in training/ and its eval entry in gaze/glc/, so the table that names
both sits here, above both layers"""

COMMANDS = Subcommands(
    prog="gazereg",
    synopsis="<command> [--preset NAME] [--dotted.option=value ...]",
    commands=SUBCOMMANDS,
    heading="commands:",
    footer="Run `gazereg <command> --help` for a command's options.",
)


def glc_main(argv: list[str] | None = None) -> int:
    """`gazereg glc <train|eval> ...`, with INFO logging to stderr."""
    return GLC.main(argv, run=run_entry_logged)


def main(argv: list[str] | None = None) -> int:
    """`gazereg COMMAND ...`: every command's errors end as one line on stderr and exit status 2 (bad usage) or
    1 (failure); `--verbose` or GAZEREG_DEBUG=1 adds the traceback (gazereg.runtime.errors)."""
    argv, verbose = split_verbose(list(sys.argv[1:] if argv is None else argv))
    if argv[:1] == ["--version"]:
        print(__version__)
        return 0

    def run(name: str, entry: Entry, rest: list[str]) -> int:
        return report_errors(f"gazereg {name}", entry, rest, verbose)

    return COMMANDS.main(argv, run=run)


if __name__ == "__main__":
    raise SystemExit(main())
