"""Progress of long work on the terminal: steps done of the total, the rate and the time left, one line a stage.

    with Progress("train baseline_s0", total=5000, unit="steps", done=1200) as bar:   # 1200 done before
        for ...:
            bar.update()                       # one more step done
            bar.note(action="0.0412")          # shown after the counts until replaced

shows ``train baseline_s0: 1800/5000 steps (36%), 2.1 steps/s, ETA 25 min 24 s, action=0.0412``. The rate
counts the work done since the bar was made (not `done`), over the seconds since then; the ETA is what is left
at that rate.

Where it goes (`default_mode`, or the `mode` given), on stderr unless another stream is given:
  tty    the stream is a terminal and this is the main process: one line redrawn in place (at most every
         `redraw_s` seconds), cut to the terminal's width, ended by a newline when the work ends or fails.
  lines  the stream is not a terminal (CI logs, `make demo 2> log`), or this is a worker process of a pool
         (whose redrawn lines would overwrite each other's on a shared terminal): a line each time another
         `every_fraction` of the total is done, or `every_s` seconds after the last line when less was done;
         nothing in the first `quiet_s` seconds, so short work writes its final line only; the final line says
         how long the work took.
  off    nothing (`enabled=False`).
Nothing is written for work that had nothing left to do. A bar only reads its clock: it draws no random
numbers and changes nothing in the work it reports on.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import shutil
import sys
import time
from collections.abc import Callable
from types import TracebackType
from typing import Literal, TextIO

Mode = Literal["tty", "lines", "off"]
CLEAR_TO_END = "\x1b[K"


def default_mode(stream: TextIO) -> Mode:
    """ "tty" for a terminal stream in the main process, "lines" otherwise (see the module docstring)."""
    try:
        tty = bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        tty = False
    return "tty" if tty and multiprocessing.parent_process() is None else "lines"


def format_duration(seconds: float) -> str:
    """'42 s', '3 min 05 s', '1 h 02 min' (rounded to whole seconds, or minutes from an hour on)."""
    s = max(0, round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    m = round(seconds / 60)
    return f"{m // 60} h {m % 60:02d} min"


def format_rate(per_s: float, unit: str) -> str:
    """'2.1 steps/s', '0.35 episodes/s', '120 steps/s'; under 0.01 a second, per minute: '0.3 episodes/min'."""
    if per_s >= 10:
        return f"{per_s:.0f} {unit}/s"
    if per_s >= 0.01:
        return f"{per_s:.2g} {unit}/s"
    return f"{60 * per_s:.2g} {unit}/min"


class Progress:
    """One stage's progress line (see the module docstring). A context manager: leaving it closes the bar.

    label: what the work is ("train baseline_s0"); total: units of work in all; unit: their name, plural;
    done: units done before this bar was made (a resumed run's); enabled: False writes nothing; mode: "tty",
    "lines" or "off" (default `default_mode(stream)`); stream: where to write (default sys.stderr when made);
    clock: seconds, monotonic (tests pass a fake one)."""

    def __init__(
        self,
        label: str,
        total: int,
        unit: str = "steps",
        *,
        done: int = 0,
        enabled: bool = True,
        mode: Mode | None = None,
        stream: TextIO | None = None,
        clock: Callable[[], float] = time.monotonic,
        every_fraction: float = 0.1,
        every_s: float = 60.0,
        quiet_s: float = 5.0,
        redraw_s: float = 0.2,
    ):
        self.label, self.unit = label, unit
        self.total, self.start = int(total), int(done)
        self.n = self.start
        self.stream = stream if stream is not None else sys.stderr
        self.mode: Mode = "off" if not enabled else (mode or default_mode(self.stream))
        self.clock = clock
        self.every_fraction, self.every_s, self.quiet_s, self.redraw_s = (
            every_fraction,
            every_s,
            quiet_s,
            redraw_s,
        )
        self.t0 = clock()
        self.notes: dict[str, str] = {}
        self._drawn_at = -math.inf  # tty: when the line was last redrawn
        self._line_at = self.t0  # lines: when the last line was written
        self._line_tick = self._tick(self.start)  # lines: the fraction tick of the last line
        self._closed = False

    # ----- what it says ---------------------------------------------------------------------------------------
    def rate(self) -> float | None:
        """Units per second since the bar was made; None before any unit was done."""
        elapsed, done = self.clock() - self.t0, self.n - self.start
        return done / elapsed if done > 0 and elapsed > 0 else None

    def eta_s(self) -> float | None:
        """Seconds left at `rate`; None while the rate is unknown."""
        rate = self.rate()
        return max(0, self.total - self.n) / rate if rate else None

    def text(self, final: bool = False) -> str:
        """The progress line (without line end); `final`: how long the work took instead of the ETA."""
        parts = [f"{self.label}: {self.n}/{self.total} {self.unit}"]
        if self.total > 0:
            parts[0] += f" ({100 * min(self.n, self.total) // self.total}%)"
        rate = self.rate()
        if rate is not None:
            parts.append(format_rate(rate, self.unit))
        if final:
            parts.append(f"took {format_duration(self.clock() - self.t0)}")
        else:
            eta = self.eta_s()
            if eta is not None:
                parts.append(f"ETA {format_duration(eta)}")
        parts += [f"{k}={v}" for k, v in self.notes.items()]
        return ", ".join(parts)

    # ----- updates --------------------------------------------------------------------------------------------
    def update(self, n: int = 1) -> None:
        """`n` more units done."""
        self.n += n
        if self.mode == "tty":
            now = self.clock()
            if now - self._drawn_at >= self.redraw_s or self.n >= self.total:
                self._draw(now)
        elif self.mode == "lines":
            self._maybe_line()

    def note(self, **values: object) -> None:
        """Values shown after the counts (name=value), replacing earlier ones of the same name."""
        self.notes.update({k: str(v) for k, v in values.items()})

    def close(self) -> None:
        """The final line (if any work was done here); idempotent."""
        if self._closed:
            return
        self._closed = True
        if self.n == self.start or self.mode == "off":
            return
        final = self.n >= self.total
        if self.mode == "tty":
            self._draw(self.clock(), "\n", final)
        else:
            self.stream.write(self.text(final) + "\n")
            self.stream.flush()

    def __enter__(self) -> Progress:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    # ----- drawing --------------------------------------------------------------------------------------------
    def _tick(self, n: int) -> int:
        """How many whole `every_fraction`s of the total `n` units are."""
        if self.total <= 0 or self.every_fraction <= 0:
            return 0
        return math.floor(n / (self.total * self.every_fraction) + 1e-9)

    def _width(self) -> int:
        """The terminal's columns (its COLUMNS, or 80, where the stream does not say)."""
        try:
            return os.get_terminal_size(self.stream.fileno()).columns
        except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation is an OSError and ValueError
            return shutil.get_terminal_size().columns

    def _draw(self, now: float, end: str = "", final: bool = False) -> None:
        """Redraw the line in place, cut to the terminal's width (a wrapped line could not be redrawn)."""
        self._drawn_at = now
        self.stream.write(f"\r{self.text(final)[: self._width() - 1]}{CLEAR_TO_END}{end}")
        self.stream.flush()

    def _maybe_line(self) -> None:
        if self.n >= self.total:  # the final line is `close`'s
            return
        now = self.clock()
        if now - self.t0 < self.quiet_s:
            return
        tick = self._tick(self.n)
        if tick > self._line_tick or now - self._line_at >= self.every_s:
            self._line_tick, self._line_at = tick, now
            self.stream.write(self.text() + "\n")
            self.stream.flush()
