"""The `gazevla` command: a thin dispatcher over library entry points.

Each subcommand lives in its own module as `main(argv: list[str]) -> int` and is imported only when it runs,
so `gazevla --help` stays fast and heavy optional dependencies load only where they are needed.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys

# name -> (module, one-line help). Only subcommands whose module is installed are offered.
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "collect": ("gazevla.envs.collect", "roll out scripted experts in simulation into an episode store"),
    "priors": ("gazevla.gaze.priors", "make per-frame gaze priors for an episode store from a gaze source"),
    "train": ("gazevla.train", "train a policy, with or without the gaze regularizer"),
    "eval": ("gazevla.evaluate", "evaluate a checkpoint in simulation (clean, lighting, sensor noise)"),
    "experiment": (
        "gazevla.experiment",
        "the end-to-end pipeline: demos, priors, training, evaluation, report",
    ),
    "glc": ("gazevla.glc.cli", "train / evaluate the GLC video gaze estimator"),
    "import": ("gazevla.data.importers", "import LeRobot v3 or HDF5 demonstrations into an episode store"),
    "viz": ("gazevla.viz.cli", "draw episodes with their gaze and attention"),
    "selfcheck": ("gazevla.selfcheck", "a short end-to-end check of the core library"),
}


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:  # a parent package is absent
        return False


def available() -> dict[str, tuple[str, str]]:
    return {name: v for name, v in SUBCOMMANDS.items() if _installed(v[0])}


def _usage() -> str:
    lines = ["usage: gazevla <command> [--preset NAME] [--dotted.option=value ...]", "", "commands:"]
    for name, (_, doc) in available().items():
        lines.append(f"  {name:<11} {doc}")
    lines += ["", "Run `gazevla <command> --help` for a command's options."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0
    if argv[0] == "--version":
        from gazevla import __version__

        print(__version__)
        return 0
    name, rest = argv[0], argv[1:]
    commands = available()
    if name not in commands:
        print(f"gazevla: unknown command {name!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    module = importlib.import_module(commands[name][0])
    return int(module.main(rest) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
