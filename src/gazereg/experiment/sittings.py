"""`gazereg sittings`: a benchmark too long for one session, run as sittings that each fit one, every finished
sitting archived (`gazereg archive`) so that its rows recompute from its episodes, and the archives pooled
(`gazereg pool`) into one report per preset.

    gazereg sittings ml45-study                          # the next sitting not archived: run (or resume), archive
    gazereg sittings ml45-study --sitting study50-s0-glc # this one (run, resumed or re-archived)
    gazereg sittings ml45-study --list                   # every sitting, archived or not
    gazereg sittings ml45-study --pool                   # each preset's archived sittings pooled into runs/
    bash scripts/libero_env.sh gazereg sittings libero-spatial

A schedule (`SCHEDULES`, by name) is one or more experiment presets ("parts", each with its own name) at some
training seeds. A sitting is one group of arms of one part at one seed: the preset's arms in groups of its
`parallel` (the arms that train side by side, one thread each on 2 cores), so a sitting trains only as long
as one arm does, or of the part's `group` (LIBERO-10: one arm a sitting, on both threads). The first group's sitting is named `<part>-s<seed>`, the others `<part>-s<seed>-<first arm>`
(`study10-s0`, `study10-s0-glc`). Order: seed by seed, and within a seed part by part, so a schedule stopped
anywhere has its parts at (nearly) the same seeds; a part's follow-up groups (`Part.core`: the groups after its
first `core`) come after every seed's core groups, seed by seed again: controls that are worth their
sittings only if the core arms show something to explain. A sitting runs

    gazereg experiment --preset P --train-seeds S --arms A B --out runs/NAME [--data-from runs/<a sitting>]
    gazereg archive runs/NAME --out docs/records/NAME

(`--data-from` the part's first sitting when that folder is here with its demonstrations, else another of
its sittings that is: the same demonstrations copied, not collected again; without it they are collected
again from the same seeds, on whatever machine the session has, so the pools take `--demos-across-machines`),
and is checked to be that command's run before it is archived. A sitting whose arms need something no sitting makes
(the ML45 study's GLC, trained on the pretraining's demonstrations) builds it first (`Prerequisite`). The
pool of a part takes the largest complete block archived so far (a pool needs each of its arms at each of its
seeds: the seeds and arm groups that give the most runs, `pool_command`);
`python scripts/update_results.py runs/<part> --marker <part>` puts it on its docs page.

Run folders are under runs/ and archives under docs/records of the working directory (the repository root);
`--records` names another archive folder. Bad input (an unknown schedule or sitting, a sitting that was run
with another configuration) is one line and exit status 2 before anything runs.
"""

from __future__ import annotations

import argparse
import itertools
import shlex
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from gazereg.experiment.config import ExperimentConfig
from gazereg.experiment.config_finetune import GLC_ML45
from gazereg.experiment.finished import stage_marker
from gazereg.experiment.pool import ACROSS_MACHINES
from gazereg.experiment.pool import main as pool_main
from gazereg.experiment.tuning import archived_run, built_config, run_experiment
from gazereg.runtime.errors import UsageError

RUNS = Path("runs")
RECORDS = Path("docs/records")


@dataclass(frozen=True)
class Step:
    """One command of a prerequisite, done when the file `done` (relative to the root) exists."""

    done: Path
    command: tuple[str, ...]


@dataclass(frozen=True)
class Prerequisite:
    """What the sittings of one arm need that no sitting makes (`what`): its steps run in order, each skipped
    when it is done, and none when the last one is."""

    arm: str
    what: str
    steps: tuple[Step, ...]

    def build(self, root: Path) -> None:
        if (root / self.steps[-1].done).exists():
            return
        print(f"{self.what} is not here: building it", flush=True)
        for step in self.steps:
            if not (root / step.done).exists():
                print(shlex.join(step.command), flush=True)
                run_experiment(step.command, root)


STUDY_GLC = Prerequisite(
    "glc",
    f"the ML45 study's GLC {GLC_ML45} (about half an hour on 2 cores)",
    (
        Step(  # the pretraining's demos stage; its train stage pauses after one step (the same command
            # without --train.stop-at continues it)
            Path("runs/pretrain/stages/demos.json"),
            ("gazereg", "pretrain", "--preset", "ml45", "--out", "runs/pretrain", "--train.stop-at", "1"),
        ),
        Step(
            GLC_ML45 / "config.json",
            (
                "gazereg",
                "glc",
                "train",
                "--store",
                "runs/pretrain/demos",
                "--gaze-source",
                "visuomotor",
                "--out",
                GLC_ML45.parent.as_posix(),
            ),
        ),  # fmt: skip
    ),
)
"""the GLC of the ML45 study's glc arm (`config_finetune.GLC_ML45`): trained only on the 45 training tasks'
demonstrations (the pretraining's, from its demos stage) with their visuomotor gaze"""


@dataclass(frozen=True)
class Part:
    """One experiment preset of a schedule: `name` prefixes its sittings and names its pool (runs/<name>);
    `core`: how many of its arm groups run seed by seed first (None: all), the rest afterwards (module
    docstring); `group`: arms per sitting (None: the preset's `parallel`; fewer when a sitting of `parallel`
    arms would not fit one session: the group's runs then share the preset's threads)."""

    name: str
    preset: str
    core: int | None = None
    group: int | None = None


@dataclass(frozen=True)
class Sitting:
    """One group of arms of one part at one training seed (module docstring)."""

    part: Part
    seed: int
    arms: tuple[str, ...]
    first_group: bool
    threads_per_run: int = 1
    """threads of each training process: the preset's `parallel` shared by the group's runs, so that a group
    smaller than `parallel` (a last arm alone) still keeps every core busy; an execution key, not part of
    what the run measured"""

    @property
    def name(self) -> str:
        base = f"{self.part.name}-s{self.seed}"
        return base if self.first_group else f"{base}-{self.arms[0]}"

    @property
    def folder(self) -> Path:
        return RUNS / self.name

    def command(self) -> list[str]:
        """The sitting's `gazereg experiment` command line, what its run is checked against."""
        cmd = ["gazereg", "experiment", "--preset", self.part.preset, "--train-seeds", str(self.seed)]
        threads = ["--threads-per-run", str(self.threads_per_run)] if self.threads_per_run > 1 else []
        return [*cmd, "--arms", *self.arms, *threads, "--out", self.folder.as_posix()]


@dataclass(frozen=True)
class Schedule:
    """Parts at training seeds (module docstring); `prerequisites` are built before a sitting of their arm."""

    parts: tuple[Part, ...]
    seeds: tuple[int, ...] = (0, 1, 2)
    prerequisites: tuple[Prerequisite, ...] = ()
    doc: str = ""

    def arm_groups(self, part: Part) -> list[tuple[str, ...]]:
        """The part's preset's arms in groups of the part's `group` (default: the preset's `parallel`), in
        order."""
        cfg = _preset(part)
        size = max(1, part.group or cfg.parallel)
        return [tuple(cfg.arms[i : i + size]) for i in range(0, len(cfg.arms), size)]

    def sitting(self, part: Part, seed: int, index: int, arms: tuple[str, ...]) -> Sitting:
        """The sitting of the part's `index`-th arm group `arms` at `seed`."""
        return Sitting(part, seed, arms, index == 0, max(1, _preset(part).parallel // len(arms)))

    def sittings(self) -> list[Sitting]:
        """Every sitting in the order they run: core groups seed by seed, then follow-up groups likewise."""
        groups = {part: list(enumerate(self.arm_groups(part))) for part in self.parts}
        phases = [
            {p: g[: p.core] for p, g in groups.items()},
            {p: [] if p.core is None else g[p.core :] for p, g in groups.items()},
        ]
        return [
            self.sitting(part, seed, i, arms)
            for phase in phases
            for seed in self.seeds
            for part in self.parts
            for i, arms in phase[part]
        ]

    def first(self, part: Part) -> Sitting:
        """The part's first sitting: its first arm group at the first seed."""
        return self.sitting(part, self.seeds[0], 0, self.arm_groups(part)[0])


def _preset(part: Part) -> ExperimentConfig:
    return built_config(("gazereg", "experiment", "--preset", part.preset))


SCHEDULES: dict[str, Schedule] = {
    "ml45-study": Schedule(
        (Part("study10", "ml45_study", core=2), Part("study50", "ml45_study50")),
        prerequisites=(STUDY_GLC,),
        doc="issue 36's study: the ML45 generalist fine-tuned on the 5 held-out tasks, 10 and 50 demos",
    ),
    "libero-spatial": Schedule((Part("libero-spatial", "libero", core=2),), doc="LIBERO-Spatial, 3 seeds"),
    "libero-object": Schedule((Part("libero-object", "libero_object", core=2),), doc="LIBERO-Object"),
    "libero-goal": Schedule((Part("libero-goal", "libero_goal", core=2),), doc="LIBERO-Goal"),
    "libero-10": Schedule(  # one arm a sitting: a pair of arms' 520-step evaluations would outlast a session
        (Part("libero-10", "libero_10", core=4, group=1),), doc="LIBERO-10 (long-horizon), one arm a sitting"
    ),
    "aloha": Schedule((Part("aloha", "aloha"),), doc="Gym-Aloha's transfer cube and insertion"),
}
"""every schedule by name (`gazereg sittings NAME`); each part's preset is one of gazereg.experiment.config's"""


def is_archived(sitting: Sitting, root: Path, records: Path = RECORDS) -> bool:
    return (root / records / sitting.name / "archive.json").exists()


def data_from(schedule: Schedule, sitting: Sitting, root: Path) -> list[str]:
    """`--data-from` the folder of another sitting of the same part that is here with its demonstrations (every
    sitting of a part collects the same setups): the part's first sitting's when it is here, else the first
    such in the schedule's order; none (collect them again) when no other one is here."""
    for other in (schedule.first(sitting.part), *schedule.sittings()):
        if (
            other.part == sitting.part
            and other != sitting
            and stage_marker(root / other.folder, "demos").exists()
        ):
            return ["--data-from", other.folder.as_posix()]
    return []


def run_sitting(schedule: Schedule, sitting: Sitting, root: Path, records: Path = RECORDS) -> Path:
    """Build the prerequisites its arms need, run (or resume) the sitting's experiment, check it is the
    command's run and archive it; the archive's path."""
    for prerequisite in schedule.prerequisites:
        if prerequisite.arm in sitting.arms:
            prerequisite.build(root)
    cmd = sitting.command()
    full = [*cmd, *data_from(schedule, sitting, root)]
    print(f"sitting {sitting.name}: {shlex.join(full)}", flush=True)
    run_experiment(full, root)
    dest = root / records / sitting.name
    archived_run(cmd, root, dest)
    return dest


def pool_command(schedule: Schedule, part: Part, root: Path, records: Path = RECORDS) -> list[str] | None:
    """`gazereg pool` into runs/<part> of the part's archived sittings: the largest complete block of them,
    the training seeds and arm groups with every (seed, group) archived that hold the most runs (ties: more
    seeds, then the earlier seeds), so a sitting that opens a seed (its first group only) does not shrink the
    pool's arms, their demonstrations pooled across machines (`pool.ACROSS_MACHINES`); None when nothing is
    archived."""
    done = {
        (s.seed, s.arms): s for s in schedule.sittings() if s.part == part and is_archived(s, root, records)
    }
    archived_seeds = sorted({seed for seed, _ in done})
    part_groups = schedule.arm_groups(part)
    best: tuple[int, tuple[int, ...], list[tuple[str, ...]]] = (0, (), [])
    for k in range(len(archived_seeds), 0, -1):
        for seeds in itertools.combinations(archived_seeds, k):
            groups = [g for g in part_groups if all((x, g) in done for x in seeds)]
            size = len(seeds) * sum(len(g) for g in groups)
            if size > best[0]:
                best = (size, seeds, groups)
    _, seeds, groups = best
    if not groups:
        return None
    runs = [(records / done[x, g].name).as_posix() for x in seeds for g in groups]
    arms = [arm for g in groups for arm in g]
    cmd = ["gazereg", "pool", "--preset", part.preset, "--train-seeds", *map(str, seeds), "--arms", *arms]
    # sittings run on whatever machine each session has: their demonstrations may differ in frames (pool.py)
    return [*cmd, "--runs", *runs, "--out", (RUNS / part.name).as_posix(), ACROSS_MACHINES]


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="gazereg sittings",
        description=(__doc__ or "").split("\n\n")[0],
        epilog="schedules: " + "; ".join(f"{name}: {s.doc}" for name, s in SCHEDULES.items()),
    )
    p.add_argument("schedule", choices=list(SCHEDULES), help="the schedule to run")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--sitting", help="run this sitting (default: the next one not archived)")
    group.add_argument("--list", action="store_true", help="list the sittings and which are archived")
    group.add_argument("--pool", action="store_true", help="only pool each part's archived sittings")
    p.add_argument(
        "--records", type=Path, default=RECORDS, help="the archives' folder (default: %(default)s)"
    )
    a = p.parse_args(list(sys.argv[1:] if argv is None else argv))
    root, schedule = Path.cwd(), SCHEDULES[a.schedule]
    sittings = schedule.sittings()
    if a.list:
        print(f"{a.schedule}: {schedule.doc}")
        for s in sittings:
            where = f"archived in {a.records / s.name}" if is_archived(s, root, a.records) else "not archived"
            print(f"{s.name}: {where}")
        return 0
    if not a.pool:
        if a.sitting is not None and a.sitting not in [s.name for s in sittings]:
            names = ", ".join(s.name for s in sittings)
            raise UsageError(f"--sitting {a.sitting!r} is not one of {a.schedule}'s sittings ({names})")
        todo = (
            [s for s in sittings if s.name == a.sitting]
            if a.sitting
            else [s for s in sittings if not is_archived(s, root, a.records)][:1]
        )
        if not todo:
            print(f"every sitting of {a.schedule} is archived")
        for s in todo:
            print(f"archived in {run_sitting(schedule, s, root, a.records).relative_to(root)}")
    for part in schedule.parts:
        if (cmd := pool_command(schedule, part, root, a.records)) is not None:
            pool_main(cmd[2:])
    return 0
