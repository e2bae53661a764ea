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
A protocol whose candidates are archived (`Protocol`: tune_photometric.py, tune_aloha.py) is one value, its
script a table and a `main`:

    PROTOCOL = Protocol("aloha", ROOT, BASE, (Candidate("default", "the preset"), ...))
    PROTOCOL.run(PROTOCOL.candidate("default"))   # run or resume, archive, record: docs/tuning/aloha/default.json
    PROTOCOL.main(argv, table, "...")             # the script's command line (--only, --table)
"""

from __future__ import annotations

import argparse
import functools
import json
import shlex
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gazereg.experiment.archive import archive
from gazereg.experiment.config import DEFAULT_PRESET, EXECUTION_KEYS, PRESETS, ExperimentConfig
from gazereg.experiment.finished import FinishedRun, Record, read_run, stage_marker
from gazereg.experiment.records import as_saved_now
from gazereg.report.ids import RunId
from gazereg.runtime.config import check_same_config, config_diff, parse, to_dict
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


def choose(successes: Mapping[str, int] | Mapping[str, tuple[float, ...]]) -> str:
    """The candidate with the most validation successes in `successes` ({name: successes}, in the
    protocol's order; or {name: (successes, tie-breakers...)}, compared in that order); ties go to the
    earlier one. ValueError when it is empty."""
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


@dataclass(frozen=True)
class Protocol:
    """A tuning protocol whose candidates are archived `gazereg experiment` runs (scripts/tune_photometric.py,
    tune_aloha.py): candidate `c` runs in `root`/runs/tune-<name>/<c> (the shared options `base`, then its
    overrides), is archived to docs/records/tune-<name>/<c> and recorded in docs/tuning/<name>/<c>.json; the
    protocol's table is docs/tuning/<name>.md. `conditions`: those its score pools (`validation_successes`).
    `pinned`: flags put between `base` and a candidate's overrides that hold the preset's values, as they were
    when the protocol was fixed, of every key a candidate changes (and of the evaluation it validates on), so
    that the candidates' commands keep building the configurations they ran after the preset takes the
    choice."""

    name: str
    root: Path
    base: tuple[str, ...]
    candidates: tuple[Candidate, ...]
    conditions: tuple[str, ...] = ("clean",)
    pinned: tuple[str, ...] = ()

    def candidate(self, name: str) -> Candidate:
        return next(c for c in self.candidates if c.name == name)

    def command(self, cand: Candidate) -> list[str]:
        """The candidate's `gazereg experiment` command line (its output folder relative to `root`)."""
        overrides = (*self.pinned, *cand.overrides)
        return experiment_command(self.base, overrides, f"runs/tune-{self.name}/{cand.name}")

    def archive_path(self, name: str) -> Path:
        return self.root / "docs" / "records" / f"tune-{self.name}" / name

    def result_path(self, name: str) -> Path:
        return self.root / "docs" / "tuning" / self.name / f"{name}.json"

    @property
    def table_path(self) -> Path:
        return self.root / "docs" / "tuning" / f"{self.name}.md"

    def finished(self, cand: Candidate) -> FinishedRun | None:
        """The candidate's archive, checked to be its command's run; None when it has none."""
        return candidate_archive(self.command(cand), self.archive_path(cand.name))

    def data_from(self, cand: Candidate) -> list[str]:
        """`--data-from` the first candidate's folder when it has its demonstrations: the candidates differ
        only in the training recipe, so they train on the same demonstrations, copied instead of collected
        again (`gazereg.experiment.reuse`)."""
        first = self.command(self.candidates[0])[-1]
        if cand != self.candidates[0] and stage_marker(self.root / first, "demos").exists():
            return ["--data-from", first]
        return []

    def run(self, cand: Candidate) -> FinishedRun:
        """Run (or resume) the candidate's experiment, archive it and write its record (`candidate_record`
        with its archive, wall time of this call and validation successes per condition) from the archive;
        the archived run."""
        t0 = time.time()
        run_experiment([*self.command(cand), *self.data_from(cand)], self.root)
        run = archived_run(self.command(cand), self.root, self.archive_path(cand.name))
        record = {"archive": self.archive_path(cand.name).relative_to(self.root).as_posix()}
        record |= candidate_record(run, cand.name, cand.change, list(cand.overrides), self.command(cand))
        record["validation_by_condition"] = {
            c: validation_successes(run.episodes(), (c,)) for c in self.conditions
        }
        record["wall_time_s_this_call"] = round(time.time() - t0, 1)
        write_record(self.result_path(cand.name), record)
        return run

    def chosen(self, scores: Mapping[str, int] | Mapping[str, tuple[float, ...]]) -> Candidate | None:
        """The chosen candidate (`choose` over `scores`, {name: score} of the candidates finished so far); None
        while a candidate has not run."""
        if len(scores) < len(self.candidates):
            return None
        return self.candidate(choose(scores))

    def chosen_from_archives(self, score: Callable[[list[Record]], Any]) -> Candidate | None:
        """The chosen candidate (`chosen`), each archived candidate scored by `score` (its evaluation records
        -> its score); None while a candidate has not run."""
        runs = {c.name: self.finished(c) for c in self.candidates}
        return self.chosen({name: score(run.episodes()) for name, run in runs.items() if run is not None})

    def recipe_diff(self, cand: Candidate, cfg: ExperimentConfig) -> dict[str, list[Any]]:
        """{train.key: [candidate `cand`'s value, `cfg`'s]} for every training-recipe key in which the
        experiment `cfg` (a preset) differs from the candidate's run, execution keys aside: {} when `cfg`
        trains its arms with the candidate's recipe."""
        ran = to_dict(built_config(tuple(self.command(cand))))
        diff = config_diff(ran, to_dict(cfg), ignore=EXECUTION_KEYS)
        return {k: v for k, v in diff.items() if k.startswith("train.")}

    def choice(self, scores: Mapping[str, int] | Mapping[str, tuple[float, ...]], rule: str) -> list[str]:
        """The lines of a table's choice under the protocol's `rule` (prose): the chosen candidate (`choose`
        over `scores`, {name: score} of the candidates finished so far) and its flags, or the candidates still
        to run."""
        lines = ["", f"Chosen ({rule}):", ""]
        best = self.chosen(scores)
        if best is None:
            todo = [c.name for c in self.candidates if c.name not in scores]
            return [*lines, "- not yet: " + ", ".join(todo) + " to run"]
        flags = shlex.join(best.overrides) or "the preset, no override"
        return [*lines, f"- **{best.name}**, {best.change}: `{flags}` in every arm's recipe"]

    def main(self, argv: Sequence[str] | None, table: Callable[[], str], description: str) -> int:
        """A protocol script's command line: run (or resume) every candidate not archived yet (`--only`:
        these), rewriting the table after each; `--table`: only the table. Exit status 2 and one line for
        an archive of another command."""
        p = argparse.ArgumentParser(description=description)
        names = [c.name for c in self.candidates]
        p.add_argument("--only", nargs="+", choices=names, help="run (or resume) these")
        p.add_argument("--table", action="store_true", help=f"only rewrite docs/tuning/{self.name}.md")
        a = p.parse_args(argv)
        try:
            todo = [] if a.table else [c for c in self.candidates if self._todo(c, a.only)]
            for cand in todo:
                print(f"candidate {cand.name}: {shlex.join(self.command(cand))}", flush=True)
                self.run(cand)
                atomic_write_text(self.table_path, table())
            self.table_path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(self.table_path, table())
        except UsageError as e:
            print(f"{p.prog}: error: {e}", file=sys.stderr)
            return 2
        print(table())
        return 0

    def _todo(self, cand: Candidate, only: Sequence[str] | None) -> bool:
        return cand.name in only if only else self.finished(cand) is None
