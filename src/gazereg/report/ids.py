"""Run identities: which arm, which training seed and, for an intermediate checkpoint, which training step.

An experiment trains every arm once per training seed; each run's checkpoints are evaluated under a name
that travels through the evaluation records (the `"arm"` field of `episodes.jsonl` / `eval_info.json`), the
stage markers and report.json. `RunId` is that name as a value; `str(run)` and `RunId.parse` are the only
places that know its text form:

    gaze@s0          the gaze arm, training seed 0, its final checkpoint
    gaze@s0#600      the same run's checkpoint at training step 600

It lives in the report package (not the experiment's) because both the report, which reads evaluation
records, and the experiment, which names its runs, need it, and the report sits below the experiment.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_TEXT = re.compile(r"^(?P<arm>[^@#]+)@s(?P<seed>\d+)(?:#(?P<step>\d+))?$")


@dataclass(frozen=True)
class RunId:
    """One training run of one arm (`step` None: its final checkpoint)."""

    arm: str
    seed: int
    step: int | None = None

    def __post_init__(self) -> None:
        if not self.arm or "@" in self.arm or "#" in self.arm:
            raise ValueError(f"an arm name must be non-empty without '@' or '#', got {self.arm!r}")
        if self.seed < 0 or (self.step is not None and self.step < 0):
            raise ValueError(f"training seed and step must be >= 0, got {self.seed}, {self.step}")

    def __str__(self) -> str:
        run = f"{self.arm}@s{self.seed}"
        return run if self.step is None else f"{run}#{self.step}"

    @classmethod
    def parse(cls, text: str) -> RunId:
        """The RunId written as `text` (`arm@sSEED` or `arm@sSEED#STEP`)."""
        m = _TEXT.match(text)
        if m is None:
            raise ValueError(f"{text!r} is not a run name (arm@sSEED or arm@sSEED#STEP, e.g. gaze@s0#600)")
        step = m.group("step")
        return cls(m.group("arm"), int(m.group("seed")), None if step is None else int(step))

    def at_step(self, step: int | None) -> RunId:
        """The same run at another checkpoint (None: the final one)."""
        return RunId(self.arm, self.seed, step)
