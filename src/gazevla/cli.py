"""The `gazevla` command: a thin dispatcher over library entry points.

Each subcommand lives in its own module as `main(argv: list[str]) -> int` and is imported only when it runs,
so `gazevla --help` stays fast and heavy optional dependencies load only where they are needed.
"""

from __future__ import annotations

import sys

from gazevla.utils.subcommands import Subcommands

# name -> ("module:function", one-line help). Only subcommands whose module is installed are offered.
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "collect": ("gazevla.envs.collect:main", "roll out scripted experts in simulation into an episode store"),
    "priors": (
        "gazevla.gaze.priors:main",
        "make per-frame gaze priors for an episode store from a gaze source",
    ),
    "train": ("gazevla.train:main", "train a policy, with or without the gaze regularizer"),
    "eval": ("gazevla.evaluate:main", "evaluate a checkpoint in simulation (clean, lighting, sensor noise)"),
    "experiment": (
        "gazevla.experiment:main",
        "the end-to-end pipeline: demos, priors, training, evaluation, report",
    ),
    "compare": (
        "gazevla.report.compare:main",
        "compare two experiment runs on the setups both evaluated (paired tests per arm and condition)",
    ),
    "glc": ("gazevla.glc.cli:main", "train / evaluate the GLC video gaze estimator"),
    "import": (
        "gazevla.data.importers:main",
        "import LeRobot v3 or HDF5 demonstrations into an episode store",
    ),
    "viz": ("gazevla.viz.cli:main", "draw episodes with their gaze and attention"),
}

COMMANDS = Subcommands(
    prog="gazevla",
    synopsis="<command> [--preset NAME] [--dotted.option=value ...]",
    commands=SUBCOMMANDS,
    heading="commands:",
    footer="Run `gazevla <command> --help` for a command's options.",
)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--version"]:
        from gazevla import __version__

        print(__version__)
        return 0
    return COMMANDS.main(argv)


if __name__ == "__main__":
    raise SystemExit(main())
