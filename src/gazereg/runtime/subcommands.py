"""Commands with subcommands (`gazereg`, `gazereg import`, `gazereg viz`): one table, one dispatcher.

A table maps each subcommand name to `"package.module:function"` and a one-line help. The module is imported
only when its subcommand runs, so listing the commands stays fast and optional dependencies load only where
they are needed; a subcommand whose module is not installed is not offered.
"""

from __future__ import annotations

import importlib
import importlib.util
import logging
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass

Entry = Callable[[list[str]], int | None]
"""A subcommand's entry point: its arguments in, an exit status (None = 0) out."""

Runner = Callable[[str, Entry, list[str]], int]
"""Runs a resolved entry point (name, entry, arguments), e.g. to turn expected errors into an exit status."""


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:  # a parent package is absent
        return False


def load_entry(target: str) -> Entry:
    """The function a `"package.module:function"` target names (importing the module)."""
    module, _, function = target.partition(":")
    return getattr(importlib.import_module(module), function)


def run_entry(name: str, entry: Entry, argv: list[str]) -> int:
    """The default runner: call the entry point, None counts as success."""
    return int(entry(argv) or 0)


def run_entry_logged(name: str, entry: Entry, argv: list[str]) -> int:
    """`run_entry` with INFO logging to stderr (`LEVEL logger: message`), for commands that report progress
    through `logging`."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    return run_entry(name, entry, argv)


@dataclass(frozen=True)
class Subcommands:
    """A dispatcher over a table of subcommands.

    `--help`, `-h` or no arguments print the usage (exit 0); an unknown name prints
    `<prog>: unknown <noun> 'name'` and the usage to stderr (exit 2)."""

    prog: str
    """the command as typed, e.g. `gazereg import`"""
    synopsis: str
    """what follows prog on the usage line, e.g. `<figure> [options]`"""
    commands: Mapping[str, tuple[str, str]]
    """name -> ("package.module:function", one-line help)"""
    heading: str = ""
    """a line above the list (e.g. `commands:`)"""
    footer: str = ""
    """a paragraph below the list"""
    noun: str = "command"
    """what a subcommand is called in the unknown-name error"""
    width: int | None = None
    """width of the name column (default: the longest name plus one)"""

    def available(self) -> dict[str, tuple[str, str]]:
        """The subcommands whose module is installed."""
        return {name: v for name, v in self.commands.items() if _installed(v[0].partition(":")[0])}

    def usage(self) -> str:
        width = self.width or max(map(len, self.commands), default=0) + 1
        lines = [f"usage: {self.prog} {self.synopsis}", ""]
        lines += [self.heading] if self.heading else []
        lines += [f"  {name:<{width}} {doc}" for name, (_, doc) in self.available().items()]
        lines += ["", self.footer] if self.footer else []
        return "\n".join(lines)

    def main(self, argv: list[str] | None = None, run: Runner = run_entry) -> int:
        """Dispatch argv (default: sys.argv[1:]) to its subcommand; returns the exit status."""
        argv = list(sys.argv[1:] if argv is None else argv)
        if not argv or argv[0] in ("-h", "--help"):
            print(self.usage())
            return 0
        name, rest = argv[0], argv[1:]
        commands = self.available()
        if name not in commands:
            print(f"{self.prog}: unknown {self.noun} {name!r}\n\n{self.usage()}", file=sys.stderr)
            return 2
        return run(name, load_entry(commands[name][0]), rest)
