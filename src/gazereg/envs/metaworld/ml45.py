"""Meta-World's ML45 benchmark split as a typed value: 45 training tasks and 5 held-out tasks (v3 names).

    split = ml45_split()      # read from the installed metaworld (metaworld.env_dict.ML45_V3)
    split.train               # 45 task names, in Meta-World's order ("assembly-v3", "basketball-v3", ...)
    split.test                # ("bin-picking-v3", "box-close-v3", "hand-insert-v3", "door-lock-v3",
                              #  "door-unlock-v3")
    split.tasks("train")      # the same as split.train; "test" and "all" likewise

Meta-World defines the split in `metaworld.env_dict.ML45_V3`, an {"train": OrderedDict, "test": OrderedDict}
of v3 task name -> environment class, and `metaworld.ML45` builds its benchmark from it; this module reads the
names from there (the installed package is the source of truth) and checks them when built: both parts
non-empty, no name twice, the two parts disjoint. Every one of the 50 tasks has a scripted expert in
`metaworld.policies.ENV_POLICY_MAP` (what `gazereg collect` rolls out: gazereg.envs.metaworld.experts) and an
instruction of its own in gazereg.envs.metaworld.instructions (tests/envs/test_ml45.py checks both).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Part = Literal["train", "test", "all"]


@dataclass(frozen=True)
class BenchmarkSplit:
    """A meta-learning benchmark's tasks: `train` (pretraining / meta-training) and `test` (held out)."""

    name: str
    train: tuple[str, ...]
    test: tuple[str, ...]

    def __post_init__(self) -> None:
        for part in ("train", "test"):
            names = getattr(self, part)
            if not names:
                raise ValueError(f"{self.name}: the {part} part is empty")
            twice = sorted({t for t in names if names.count(t) > 1})
            if twice:
                raise ValueError(f"{self.name}: the {part} part lists {twice} more than once")
        both = sorted(set(self.train) & set(self.test))
        if both:
            raise ValueError(f"{self.name}: {both} are both training and held-out tasks")

    @property
    def all(self) -> tuple[str, ...]:
        """Training tasks, then the held-out ones."""
        return self.train + self.test

    def tasks(self, part: Part) -> tuple[str, ...]:
        """The task names of `part` ("train", "test" or "all"); ValueError for another part."""
        if part == "train":
            return self.train
        if part == "test":
            return self.test
        if part == "all":
            return self.all
        raise ValueError(f"unknown part {part!r} of {self.name}; use train, test or all")


def ml45_split() -> BenchmarkSplit:
    """Meta-World ML45's split, read from the installed metaworld (ImportError without it)."""
    from metaworld.env_dict import ML45_V3

    return BenchmarkSplit("ML45", tuple(ML45_V3["train"]), tuple(ML45_V3["test"]))
