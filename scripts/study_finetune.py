"""The fine-tuning study's sittings (issue 36 item 4; docs/pretraining.md, "The study"): two arms of one
training seed of one study preset a sitting, archived when it finishes; the archived sittings pooled into one
report per preset.

    .venv/bin/python scripts/study_finetune.py                           # the next sitting not archived yet
    .venv/bin/python scripts/study_finetune.py --sitting study50-s0-glc  # this one (run, resumed or re-archived)
    .venv/bin/python scripts/study_finetune.py --list                    # every sitting, archived or not
    .venv/bin/python scripts/study_finetune.py --pool                    # each preset's archived sittings pooled

A seed's four arms are two sittings (`ARM_PAIRS`): baseline and gaze (named `study10-s0`), then glc and uniform
(`study10-s0-glc`), each pair training side by side on one thread each. All four in one sitting took longer
than a session on 2 cores (about 2.5 h of training and evaluation, plus the GLC's prerequisites on a fresh
machine), and a machine's runs/ does not outlive its session. Order: both pairs of study10-s0, both of
study50-s0, then seed 1, then seed 2 (`ml45_study` is 10 demonstrations per task, `ml45_study50` 50), so the
study stopped anywhere has both counts at (nearly) the same seeds. A sitting runs

    gazereg experiment --preset P --train-seeds S --arms A B --out runs/NAME [--data-from runs/<P's first sitting>]
    gazereg archive runs/NAME --out docs/records/NAME

(`--data-from` when that folder is here: the same demonstrations copied, not collected again; without it they
are collected again from the same seeds), checked to be that command's run before it is archived. A glc
pair's sitting first builds the study's GLC (`config_finetune.GLC_ML45`) when it is not here (`build_glc`,
about half an hour). `--pool`
writes runs/study10 and runs/study50 (`gazereg pool` over the archived sittings of the arms every archived seed
has), which `python scripts/update_results.py runs/study10 --marker study10` puts on docs/pretraining.md.
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from gazereg.experiment.config_finetune import GLC_ML45
from gazereg.experiment.tuning import archived_run, run_experiment
from gazereg.runtime.errors import UsageError

ROOT = Path(__file__).resolve().parents[1]
RECORDS = "docs/records"
PRESETS = {"study10": "ml45_study", "study50": "ml45_study50"}
SEEDS = (0, 1, 2)
ARM_PAIRS = (("baseline", "gaze"), ("glc", "uniform"))
"""the study's arms two per sitting, in the order they run; the first pair's sitting is named after its seed
alone (its folder the others copy the demonstrations from), the others by their first arm"""
PRETRAIN_DEMOS = ["gazereg", "pretrain", "--preset", "ml45", "--out", "runs/pretrain", "--train.stop-at", "1"]
"""the pretraining's demonstrations of the 45 training tasks, the GLC's data (its demos stage; the train stage
pauses after one step, and the same command without --train.stop-at continues it)"""
GLC_TRAIN = [
    "gazereg", "glc", "train", "--store", "runs/pretrain/demos", "--gaze-source", "visuomotor", "--out",
    GLC_ML45.parent.as_posix(),
]  # fmt: skip
"""the study's GLC (its final/ folder is `GLC_ML45`), trained on the 45 training tasks' visuomotor gaze"""


@dataclass(frozen=True)
class Sitting:
    """Two arms at one training seed of one study preset: its run folder runs/<name> and archive
    docs/records/<name>."""

    study: str  # "study10" | "study50"
    seed: int
    arms: tuple[str, ...] = ARM_PAIRS[0]

    @property
    def name(self) -> str:
        base = f"{self.study}-s{self.seed}"
        return base if self.arms == ARM_PAIRS[0] else f"{base}-{self.arms[0]}"

    @property
    def needs_glc(self) -> bool:
        return "glc" in self.arms

    @property
    def preset(self) -> str:
        return PRESETS[self.study]

    @property
    def archive(self) -> Path:
        return ROOT / RECORDS / self.name

    def archived(self) -> bool:
        return (self.archive / "archive.json").exists()

    def command(self) -> list[str]:
        """The sitting's `gazereg experiment` command line (relative to the repository's root), what its run is
        checked against."""
        cmd = ["gazereg", "experiment", "--preset", self.preset, "--train-seeds", str(self.seed)]
        return [*cmd, "--arms", *self.arms, "--out", f"runs/{self.name}"]

    def data_from(self) -> list[str]:
        """`--data-from` the preset's first sitting's folder when it is here and has its demonstrations."""
        first = Sitting(self.study, SEEDS[0])
        folder = f"runs/{first.name}"
        if self != first and (ROOT / folder / "stages" / "demos.json").exists():
            return ["--data-from", folder]
        return []


SITTINGS = [Sitting(study, seed, arms) for seed in SEEDS for study in PRESETS for arms in ARM_PAIRS]
NAMES = [s.name for s in SITTINGS]


def run_sitting(sitting: Sitting) -> Path:
    """Run (or resume) the sitting's experiment, check it is the command's run and archive it; the archive."""
    if sitting.needs_glc:
        build_glc()
    cmd, data_from = sitting.command(), sitting.data_from()
    print(f"sitting {sitting.name}: {shlex.join([*cmd, *data_from])}", flush=True)
    run_experiment([*cmd, *data_from], ROOT)
    archived_run(cmd, ROOT, sitting.archive)
    return sitting.archive


def build_glc() -> None:
    """The study's GLC (`GLC_ML45`) when it is not here: the pretraining's demonstrations unless they are here
    (`PRETRAIN_DEMOS`), then the GLC trained on them (`GLC_TRAIN`); about half an hour on 2 cores."""
    if (ROOT / GLC_ML45 / "config.json").exists():
        return
    print(f"the study's GLC {GLC_ML45} is not here: building it", flush=True)
    if not (ROOT / "runs" / "pretrain" / "stages" / "demos.json").exists():
        print(shlex.join(PRETRAIN_DEMOS), flush=True)
        run_experiment(PRETRAIN_DEMOS, ROOT)
    print(shlex.join(GLC_TRAIN), flush=True)
    run_experiment(GLC_TRAIN, ROOT)


def next_sitting() -> list[Sitting]:
    """The first sitting not archived yet (none when every one is)."""
    return [s for s in SITTINGS if not s.archived()][:1]


def pool_command(study: str) -> list[str] | None:
    """`gazereg pool` into runs/<study> of `study`'s archived sittings: the seeds with an archived sitting,
    at the arm pairs every one of them has archived (a pool needs each arm at each seed); None when none is."""
    done = [s for s in SITTINGS if s.study == study and s.archived()]
    seeds = sorted({s.seed for s in done})
    pairs = [p for p in ARM_PAIRS if all(Sitting(study, seed, p) in done for seed in seeds)]
    if not done or not pairs:
        return None
    runs = [s for s in done if s.arms in pairs]
    arms = [arm for p in pairs for arm in p]
    cmd = ["gazereg", "pool", "--preset", PRESETS[study], "--train-seeds", *map(str, seeds), "--arms", *arms]
    return [*cmd, "--runs", *(f"{RECORDS}/{s.name}" for s in runs), "--out", f"runs/{study}"]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sitting", choices=NAMES, help="run this sitting (default: the next one not archived)")
    p.add_argument("--list", action="store_true", help="list the sittings and which are archived")
    p.add_argument("--pool", action="store_true", help="only pool each preset's archived seeds")
    a = p.parse_args(argv)
    if a.list:
        for s in SITTINGS:
            print(f"{s.name}: {'archived in ' + RECORDS + '/' + s.name if s.archived() else 'not run'}")
        return 0
    try:
        if not a.pool:
            todo = [s for s in SITTINGS if s.name == a.sitting] if a.sitting else next_sitting()
            if not todo:
                print("every sitting is archived")
            for s in todo:
                print(f"archived in {run_sitting(s).relative_to(ROOT)}")
        for study in PRESETS:
            if (cmd := pool_command(study)) is not None:
                subprocess.run([sys.executable, "-m", "gazereg.cli", *cmd[1:]], cwd=ROOT, check=True)
    except UsageError as e:
        print(f"{Path(__file__).name}: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
