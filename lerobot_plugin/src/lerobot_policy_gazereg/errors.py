"""How the plugin refuses a gaze option, camera or gaze column it cannot use: one line naming it.

Library code raises `GazeUsageError` (a ValueError, so Python callers catch it as before). Inside a LeRobot
command (lerobot-train, lerobot-eval, ... : a `lerobot.scripts.*` module on the stack) the plugin's entry points
(`refusing()`: the config's __post_init__ and feature hook, the policy's __init__ and training forward) turn it
into one line on stderr, `<program>: error: --policy.<option>: <problem>`, and exit status 2. That is needed
because LeRobot's command line would otherwise lose or bury the message: draccus turns a ValueError raised while
it builds a config into "Couldn't instantiate class ... using the given arguments" without the cause, and an
error raised while training prints a traceback.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

SCRIPTS_PACKAGE = "lerobot.scripts."


class GazeUsageError(ValueError):
    """A gaze option, camera or gaze column the plugin cannot use.

    option: what the user set, as `--policy.<option>` names it (e.g. "gaze_weight", "gaze_key=gaze.point"), or
    None; problem: one line saying what is wrong and, where it helps, what is accepted."""

    def __init__(self, option: str | None, problem: str):
        self.option = option
        self.problem = problem
        super().__init__(f"{option}: {problem}" if option else problem)

    def cli_line(self) -> str:
        """The message as the command line names the option: `--policy.<option>: <problem>`."""
        return f"--policy.{self.option}: {self.problem}" if self.option else self.problem


def _module_names(frame) -> Iterator[str]:
    while frame is not None:
        g = frame.f_globals
        yield str(g.get("__name__", ""))
        spec = g.get("__spec__")
        if spec is not None and getattr(
            spec, "name", None
        ):  # `python -m lerobot.scripts.x`: __name__ is __main__
            yield str(spec.name)
        frame = frame.f_back


def in_lerobot_command() -> bool:
    """True when a LeRobot command's module (lerobot.scripts.*) is on the call stack."""
    return any(name.startswith(SCRIPTS_PACKAGE) for name in _module_names(sys._getframe(1)))


@contextmanager
def refusing() -> Iterator[None]:
    """Re-raise a GazeUsageError, or, inside a LeRobot command, print it as one line and exit with status 2."""
    try:
        yield
    except GazeUsageError as e:
        if not in_lerobot_command():
            raise
        prog = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else "lerobot"
        sys.stdout.flush()
        print(f"{prog}: error: {e.cli_line()}", file=sys.stderr, flush=True)
        raise SystemExit(2) from None
