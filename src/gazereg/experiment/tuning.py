"""What the tuning scripts share (scripts/tune_baseline.py, tune_finetune.py, tune_photometric.py): a candidate is
one `gazereg experiment` run on validation setups (neither training nor evaluation setups), read back through
the one reader `read_run` (its run folder or its archive), scored by its validation successes (clean, or pooled
over the conditions a protocol names).

    cand = Candidate("lr1e-4", "learning rate 1e-4", ("--train.optim.lr", "1e-4"))
    cmd = experiment_command(BASE, cand.overrides, "runs/tune/lr1e-4")   # ["gazereg", "experiment", ...]
    run_experiment(cmd, root)                                           # run or resume it (stages resume)
    run = archived_run(cmd, root, Path("docs/records/tune/lr1e-4"))     # checked, archived, read back
    val = validation_successes(run.episodes())                          # {task: {seed: [successes, n]}}
    write_record(path, candidate_record(run, cand.name, cand.change, list(cand.overrides), cmd))
    choose({"default": 37, "lr1e-4": 45})                               # "lr1e-4"

The choice rule of every script (`choose`): the most validation successes, ties to the earlier candidate.
"""

from __future__ import annotations

import functools
import json
import shlex
import subprocess
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gazereg.experiment.archive import archive
from gazereg.experiment.config import DEFAULT_PRESET, EXECUTION_KEYS, PRESETS, ExperimentConfig
from gazereg.experiment.finished import FinishedRun, Record, read_run
from gazereg.experiment.records import as_saved_now
from gazereg.report.ids import RunId
from gazereg.runtime.config import check_same_config, parse
from gazereg.runtime.errors import UsageError
from gazereg.runtime.io import atomic_write_text

Validation = dict[str, dict[str, list[int]]]
"""{task: {training seed (text): [successes, episodes]}} of a candidate's clean validation episodes"""


@dataclass(frozen=True)
class Candidate:
    """One tuning candidate: its name (its run folder's and record's), what it changes (prose for the
    table) and its command-line overrides (after the shared command's options)."""

    name: str
    change: str
    overrides: tuple[str, ...] = ()


def experiment_command(base: Sequence[str], overrides: Sequence[str], out: str) -> list[str]:
    """`gazereg experiment` with the shared options `base`, then `overrides`, writing into `out`."""
    return ["gazereg", "experiment", *base, *overrides, "--out", out]


def run_experiment(command: Sequence[str], root: Path) -> None:
    """Run `command` (a `gazereg ...` command line) in `root` with this interpreter; an existing run folder
    resumes (finished stages are skipped). CalledProcessError when it fails."""
    subprocess.run([sys.executable, "-m", "gazereg.cli", *command[1:]], cwd=root, check=True)


@functools.cache
def built_config(command: tuple[str, ...]) -> ExperimentConfig:
    """The configuration the `gazereg experiment` command line `command` builds (UsageError, one line, for
    a bad option); cached, as a command builds the same configuration every time in one process."""
    return parse(PRESETS, list(command[2:]), prog=" ".join(command[:2]), default=DEFAULT_PRESET)


def check_candidate(run: FinishedRun, command: Sequence[str]) -> None:
    """UsageError (one line, naming each differing key) when the finished `run` was not made by the
    `gazereg experiment` command line `command`: its saved configuration must be the one `command` builds
    but for the execution keys and the output folder."""
    built = built_config(tuple(command))
    check_same_config(
        as_saved_now(run.config, run.path, built),
        built,
        (*EXECUTION_KEYS, "out"),
        run.path,
        f"it is not the candidate `{shlex.join(command)}`",
    )


def archived_run(command: Sequence[str], root: Path, dest: Path) -> FinishedRun:
    """The finished run of `command` (a `gazereg experiment` command line ending in `--out FOLDER`, relative to
    `root`), checked to be that command's (`check_candidate`), archived to `dest` (`gazereg archive`) and read
    back from the archive: what a candidate's row and record are made from."""
    source = root / command[list(command).index("--out") + 1]
    check_candidate(read_run(source), command)
    return read_run(archive(source, dest))


def candidate_archive(command: Sequence[str], dest: Path) -> FinishedRun | None:
    """The archive `dest` of a candidate (`read_run`), checked to be the run of its command (`check_candidate`);
    None when it has none yet."""
    if not dest.exists():
        return None
    run = read_run(dest)
    check_candidate(run, command)
    return run


def validation_successes(episodes: list[Record], conditions: Sequence[str] = ("clean",)) -> Validation:
    """{task: {training seed: [successes, episodes]}} of those of an experiment's evaluation records under
    `conditions` (the clean ones by default), pooled over them."""
    out: Validation = {}
    for ep in episodes:
        if ep["condition"] not in conditions:
            continue
        seed = str(RunId.parse(ep["arm"]).seed)
        cell = out.setdefault(ep["task"], {}).setdefault(seed, [0, 0])
        cell[0] += int(ep["success"])
        cell[1] += 1
    return out


def totals(val: Validation) -> tuple[int, int]:
    """(successes, episodes) over every task and training seed of `val`."""
    cells = [c for seeds in val.values() for c in seeds.values()]
    return sum(c[0] for c in cells), sum(c[1] for c in cells)


def rate_text(val: Validation) -> str:
    """ "k/n = 0.xx", the successes over every task and seed of `val`."""
    k, n = totals(val)
    return f"{k}/{n} = {k / n:.2f}"


def per_task_text(val: Validation) -> str:
    """ "task k/n, ..." over the training seeds, tasks in `val`'s order."""
    return ", ".join(
        f"{task} {sum(c[0] for c in seeds.values())}/{sum(c[1] for c in seeds.values())}"
        for task, seeds in val.items()
    )


def per_seed_text(val: Validation) -> str:
    """ "s0 k, s1 k" over the tasks, training seeds in increasing order."""
    seeds = sorted({s for t in val.values() for s in t})
    return ", ".join(f"s{s} {sum(val[t][s][0] for t in val)}" for s in seeds)


def choose(successes: Mapping[str, int]) -> str:
    """The candidate with the most validation successes in `successes` ({name: successes}, in the
    protocol's order); ties go to the earlier one. ValueError when it is empty."""
    if not successes:
        raise ValueError("no candidate to choose from")
    names = list(successes)
    return max(names, key=lambda n: (successes[n], -names.index(n)))


def candidate_record(
    run: FinishedRun, name: str, change: str, overrides: list[str], command: Sequence[str]
) -> dict[str, Any]:
    """Candidate `name`'s record (less the wall time of the call that ran it) from its finished experiment
    `run` (a run folder or its archive): its command, stage times (s), machine, date and validation
    successes per task and training seed. UsageError when the run has no report yet."""
    report = run.report
    if report is None:
        raise UsageError(f"{run.path} has no report.json: rerun its experiment to finish the report stage")
    return {
        "candidate": name,
        "change": change,
        "overrides": overrides,
        "command": shlex.join(command),
        "stage_seconds": report["stage_times_s"],
        "wall_time_s": report["wall_time_s"],
        "machine": report["machine"]["summary"],
        "date": report["date"],
        "validation": validation_successes(run.episodes()),
    }


def write_record(path: Path, record: dict[str, Any]) -> None:
    """Write a candidate's record to `path` as indented JSON, whole or not at all."""
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(record, indent=1) + "\n")


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """The lines of a markdown table of `rows` under `header`."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]
