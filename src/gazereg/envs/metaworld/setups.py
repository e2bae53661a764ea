"""Named ranges of Meta-World setup seeds, so that no two uses of the simulator share a setup.

A setup seed s is setup s % 50 of `metaworld.MT1(task, seed=s // 50)` (gazereg.envs.metaworld.env): distinct
seeds are distinct object and goal positions. Every command but `gazereg pretrain` draws its setups from
EXPERIMENTS (seeds below 100,000):

    training demonstrations   0 ..                 `gazereg collect` (seed_base 0) and the experiment's demos
                                                   stage: demos plus replacements of the expert's failures,
                                                   at most 1,000 per task (collect_config.INDEX_STRIDE)
    evaluation                eval.seed_start ..   1,000 by default (`gazereg eval`, the experiment's eval and
                                                   converge stages)
    validation (tuning)       1,300 ..             scripts/tune_baseline.py (its --eval.seed-start)
    alignment episodes        eval start + 500 ..  the experiment's held-out store (experiment.demos)
    GLC demonstrations        eval start + 700 ..  the experiment's GLC store (experiment.demos)

`gazereg pretrain` (gazereg.experiment.pretrain) has ranges of its own above them: PRETRAIN_DEMOS for its
demonstrations (1,000 seeds per task: demos plus replacements) and PRETRAIN_EVAL for its multi-task
evaluation. tests/envs/test_ml45.py checks that the ranges here are disjoint and that every preset of the other
commands stays inside EXPERIMENTS.
"""

from __future__ import annotations

from dataclasses import dataclass

from gazereg.runtime.errors import UsageError


@dataclass(frozen=True)
class SetupRange:
    """Setup seeds start .. stop - 1 reserved for one use (`purpose`)."""

    name: str
    start: int
    stop: int
    purpose: str

    def __post_init__(self) -> None:
        if not 0 <= self.start < self.stop:
            raise ValueError(
                f"setup range {self.name}: need 0 <= start < stop, got {self.start}, {self.stop}"
            )

    @property
    def seeds(self) -> range:
        return range(self.start, self.stop)

    def __len__(self) -> int:
        return self.stop - self.start

    def overlaps(self, other: SetupRange | range) -> bool:
        """Whether any seed is in both (`other` a range of step 1)."""
        return max(self.start, other.start) < min(self.stop, other.stop)

    def contains(self, seeds: range) -> bool:
        """Whether every seed of `seeds` (a range of step 1) is in this range."""
        return len(seeds) == 0 or (self.start <= seeds.start and seeds.stop <= self.stop)

    def require(self, seeds: range, what: str) -> None:
        """UsageError unless `seeds` lie inside this range; `what` names the option or the use."""
        if not self.contains(seeds):
            raise UsageError(
                f"{what}: setup seeds {seeds.start}..{seeds.stop - 1} leave the {self.name} range "
                f"{self.start}..{self.stop - 1} ({self.purpose}); use fewer"
            )


EXPERIMENTS = SetupRange(
    "experiments",
    0,
    100_000,
    "every other command: training demonstrations from 0, evaluation from 1,000, validation from 1,300, "
    "alignment and GLC demonstrations at +500 and +700 past the evaluation's first seed",
)
PRETRAIN_DEMOS = SetupRange(
    "pretrain_demos", 100_000, 101_000, "`gazereg pretrain`'s demonstrations, replacements included"
)
PRETRAIN_EVAL = SetupRange("pretrain_eval", 101_000, 102_000, "`gazereg pretrain`'s multi-task evaluation")
RANGES = (EXPERIMENTS, PRETRAIN_DEMOS, PRETRAIN_EVAL)
"""every named range; pairwise disjoint"""
