"""The fine-tuning study's sittings (issue 36 item 4; docs/pretraining.md, "The study"): one training seed of one
study preset a sitting, archived when it finishes; each preset's archived seeds pooled into one report.

    .venv/bin/python scripts/study_finetune.py                       # the next sitting not archived yet
    .venv/bin/python scripts/study_finetune.py --sitting study50-s0  # this one (run, resumed or re-archived)
    .venv/bin/python scripts/study_finetune.py --list                # every sitting, archived or not
    .venv/bin/python scripts/study_finetune.py --pool                # each preset's archived seeds pooled

Order: study10-s0, study50-s0, study10-s1, study50-s1, study10-s2, study50-s2 (`ml45_study` is 10
demonstrations per task, `ml45_study50` 50): both demonstration counts of a seed before the next seed, so the
study stopped anywhere has both counts at (nearly) the same seeds. A sitting runs

    gazereg experiment --preset P --train-seeds S --out runs/NAME [--data-from runs/<P's seed-0 sitting>]
    gazereg archive runs/NAME --out docs/records/NAME

(`--data-from` when that folder is here: the same demonstrations copied, not collected again; without it they
are collected again from the same seeds), checked to be that command's run before it is archived. The study's
GLC (`config_finetune.GLC_ML45`) must exist first: the error names its command. `--pool` writes
runs/study10 and runs/study50 (`gazereg pool` over the archives of the seeds archived so far), which
`python scripts/update_results.py runs/study10 --marker study10` puts on docs/pretraining.md.
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
GLC_COMMAND = "gazereg glc train --store runs/pretrain/demos --gaze-source visuomotor --out runs/glc-ml45"


@dataclass(frozen=True)
class Sitting:
    """One training seed of one study preset: its run folder runs/<name> and archive docs/records/<name>."""

    study: str  # "study10" | "study50"
    seed: int

    @property
    def name(self) -> str:
        return f"{self.study}-s{self.seed}"

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
        return [*cmd, "--out", f"runs/{self.name}"]

    def data_from(self) -> list[str]:
        """`--data-from` the preset's first sitting's folder when it is here and has its demonstrations."""
        first = f"runs/{Sitting(self.study, SEEDS[0]).name}"
        if self.seed != SEEDS[0] and (ROOT / first / "stages" / "demos.json").exists():
            return ["--data-from", first]
        return []


SITTINGS = [Sitting(study, seed) for seed in SEEDS for study in PRESETS]
NAMES = [s.name for s in SITTINGS]


def run_sitting(sitting: Sitting) -> Path:
    """Run (or resume) the sitting's experiment, check it is the command's run and archive it; the archive."""
    if not (ROOT / GLC_ML45 / "config.json").exists():
        raise UsageError(f"the study's GLC {GLC_ML45} is not here; train it first: {GLC_COMMAND}")
    cmd, data_from = sitting.command(), sitting.data_from()
    print(f"sitting {sitting.name}: {shlex.join([*cmd, *data_from])}", flush=True)
    run_experiment([*cmd, *data_from], ROOT)
    archived_run(cmd, ROOT, sitting.archive)
    return sitting.archive


def next_sitting() -> list[Sitting]:
    """The first sitting not archived yet (none when every one is)."""
    return [s for s in SITTINGS if not s.archived()][:1]


def pool_command(study: str) -> list[str] | None:
    """`gazereg pool` of `study`'s archived seeds into runs/<study>; None when none is archived."""
    done = [s for s in SITTINGS if s.study == study and s.archived()]
    if not done:
        return None
    cmd = ["gazereg", "pool", "--preset", PRESETS[study], "--train-seeds", *(str(s.seed) for s in done)]
    return [*cmd, "--runs", *(f"{RECORDS}/{s.name}" for s in done), "--out", f"runs/{study}"]


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
