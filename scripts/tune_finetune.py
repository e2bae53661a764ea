"""Tune the fine-tuning study's gaze term on validation setups that are neither training nor evaluation setups
(issue 36 item 3): the fine-tuning recipe first, gaze blind, then the gaze term's weight, query set and layers.

    .venv/bin/python scripts/tune_finetune.py                       # every candidate not yet run, step by step
    .venv/bin/python scripts/tune_finetune.py --step weight         # one step's candidates not yet run
    .venv/bin/python scripts/tune_finetune.py --only w1e-2 w1       # some candidates (run or resumed)
    .venv/bin/python scripts/tune_finetune.py --table               # only rewrite docs/tuning/finetune.md

Protocol (fixed on 2026-11-27, before any fine-tuning result existed):
- Shared command: `gazereg experiment --preset ml45_finetune --eval.seed-start 1300 --eval.episodes 20
  --convergence-points 1 --heldout-per-task 1`: the committed ML45 generalist (models/ml45) fine-tuned on
  ML45's 5 held-out tasks, 10 demonstrations per task, one training seed (0). Validation: Meta-World setups
  1300..1319 of each held-out task, clean: 100 episodes per candidate. Training uses setups 0.. of the same
  tasks and the study's evaluation 1000..1024: disjoint.
- Step `recipe` (arm baseline only, no gaze anywhere): candidates `ft-default` (the preset: lr 5e-4, batch 32,
  3,000 steps), `ft-lr1e-4` (--train.optim.lr 1e-4), `ft-lr1e-3` (--train.optim.lr 1e-3), `ft-steps6k`
  (--train.steps 6000). Choice: the most validation successes, ties to the earlier candidate.
- Step `recipe-scratch` (added on 2026-11-27, before any tuning result, after the preset recipe's pretrained run
  did not beat scratch at 10 demonstrations): the same four recipe candidates for `ml45_scratch` (the same
  policy from random weights: `sc-default`, `sc-lr1e-4`, `sc-lr1e-3`, `sc-steps6k`), so that "does pretraining
  help" compares each initialisation at its own best recipe. Off the chain: the later steps take the `recipe`
  step's choice, never this one's.
- Step `generalist` (added on 2026-11-27, before its result, after the recipe steps left the generalist's lead
  over scratch not significant, 25 against 20 of 100): which generalist the gaze steps fine-tune, at the recipe
  step's choice, gaze blind. The committed one (the recipe step's chosen run, not rerun) against `g-continued`,
  the longer-pretrained `gazereg pretrain --preset ml45_continued` (the committed one trained 30,000 steps
  more; its policy in runs/pretrain-continued/policy, --train.init-from). Choice as above (ties keep the
  committed one); the later steps fine-tune the chosen generalist.
- Step `weight` (arm gaze only, the visuomotor prior, on the chosen recipe's overrides): `w1e-3`, `w1e-2`,
  `w1e-1`, `w1`, `w10` (--train.gaze.weight; the gaze KL against the action loss's scale), action queries,
  default layers (-2 -1). Choice as above (ties to the smaller weight, the earlier).
- Step `queries` (the chosen recipe and weight): `q-language`, `q-both` (--train.gaze.queries); the action
  candidate is the chosen weight's run (not rerun), first in the step's order (ties keep it).
- Step `layers` (the chosen recipe, weight and queries): `l-early` (--train.gaze.layers 0), `l-middle`
  (--train.gaze.layers 1 2), `l-last` (--train.gaze.layers 3); the default (-2 -1, i.e. layers 2 3 of 4) is
  the queries step's chosen run (not rerun), first in the step's order (ties keep it).
- A step runs only when the previous step has finished (otherwise the candidates still missing are named,
  exit 2). The final choice is the layers step's: its overrides are the flags the study uses.
Each finished candidate `runs/tune-ft/<name>` is archived as `gazereg archive runs/tune-ft/<name> --out
docs/records/tune-ft/<name>` (so its row recomputes from its episodes) and recorded in
docs/tuning/finetune/<name>.json (its command, wall time and validation successes per task and training
seed). docs/tuning/finetune.md, the table of every candidate, is read from the archives (`read_run`); for a
gaze candidate it shows the gaze term's scale: the weight times the final training gaze KL against the final
action loss (the last logged training record, mean over the candidate's training runs).
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from gazereg.experiment.finished import FinishedRun
from gazereg.experiment.tuning import (
    Candidate,
    archived_run,
    candidate_archive,
    candidate_record,
    choose,
    experiment_command,
    markdown_table,
    per_task_text,
    rate_text,
    run_experiment,
    totals,
    validation_successes,
    write_record,
)
from gazereg.runtime.errors import UsageError
from gazereg.runtime.io import atomic_write_text

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "tuning"
RECORDS = ROOT / "docs" / "records" / "tune-ft"
RUNS = "runs/tune-ft"
BASE = [
    "--eval.seed-start", "1300", "--eval.episodes", "20",
    "--convergence-points", "1", "--heldout-per-task", "1",
]  # fmt: skip


CONTINUED = ("--train.init-from", "runs/pretrain-continued/policy")
"""the longer-pretrained generalist (`gazereg pretrain --preset ml45_continued`)"""


@dataclass(frozen=True)
class Step:
    """One tuning step: its arm, and its candidates' own changes (on the earlier steps' chosen overrides);
    `default`: what the previous step's chosen run has of the setting tuned here, that run then being this
    step's first candidate (not rerun); None: no run is carried over. `preset`: the experiment preset its
    commands start from; `chained` False: a step beside the chain (its candidates' changes on the preset
    alone, its choice passed on to no later step)."""

    name: str
    arm: str
    candidates: tuple[Candidate, ...]
    default: str | None = None
    preset: str = "ml45_finetune"
    chained: bool = True


def _c(name: str, change: str, *overrides: str) -> Candidate:
    return Candidate(name, change, overrides)


def _recipe(prefix: str) -> tuple[Candidate, ...]:
    return (
        _c(f"{prefix}-default", "the preset: lr 5e-4, batch 32, 3,000 steps"),
        _c(f"{prefix}-lr1e-4", "learning rate 1e-4", "--train.optim.lr", "1e-4"),
        _c(f"{prefix}-lr1e-3", "learning rate 1e-3", "--train.optim.lr", "1e-3"),
        _c(f"{prefix}-steps6k", "6,000 steps", "--train.steps", "6000"),
    )


STEPS = (
    Step("recipe", "baseline", _recipe("ft")),
    Step("recipe-scratch", "baseline", _recipe("sc"), preset="ml45_scratch", chained=False),
    Step("generalist", "baseline", (
        _c("g-continued", "the longer-pretrained generalist (ml45_continued)", *CONTINUED),
    ), default="the committed generalist (models/ml45)"),
    Step("weight", "gaze", tuple(
        _c(f"w{w}", f"gaze weight {w}", "--train.gaze.weight", w) for w in ("1e-3", "1e-2", "1e-1", "1", "10")
    )),
    Step("queries", "gaze", (
        _c("q-language", "the instruction's queries", "--train.gaze.queries", "language"),
        _c("q-both", "the action and the instruction's queries", "--train.gaze.queries", "both"),
    ), default="the action queries"),
    Step("layers", "gaze", (
        _c("l-early", "layer 0 (early)", "--train.gaze.layers", "0"),
        _c("l-middle", "layers 1 and 2 (middle)", "--train.gaze.layers", "1", "2"),
        _c("l-last", "layer 3 (the last)", "--train.gaze.layers", "3"),
    ), default="layers -2 -1 (2 and 3 of 4)"),
)  # fmt: skip
NAMES = [c.name for step in STEPS for c in step.candidates]


@dataclass(frozen=True)
class Entry:
    """A candidate as the protocol places it now: its step, its overrides on the shared command (the earlier
    steps' chosen ones first; None while an earlier step is unfinished), and its archive (None: not run)."""

    step: Step
    candidate: Candidate
    overrides: tuple[str, ...] | None
    run: FinishedRun | None
    carried: bool = False

    @property
    def command(self) -> list[str]:
        if self.overrides is None:
            raise ValueError(f"{self.candidate.name}: an earlier step is unfinished")
        base = ["--preset", self.step.preset, *BASE, "--arms", self.step.arm]
        return experiment_command(base, self.overrides, f"{RUNS}/{self.candidate.name}")

    @property
    def successes(self) -> int:
        if self.run is None:
            raise ValueError(f"{self.candidate.name} has not run")
        return totals(validation_successes(self.run.episodes()))[0]


def archive_path(name: str) -> Path:
    return RECORDS / name


def result_path(name: str) -> Path:
    return DOCS / "finetune" / f"{name}.json"


def read_archive(entry: Entry) -> FinishedRun | None:
    """The candidate's archive, checked to be its command's run; None when it has none."""
    return candidate_archive(entry.command, archive_path(entry.candidate.name))


def plan() -> list[tuple[Step, list[Entry], Entry | None]]:
    """Every step as the archives place it: (step, its entries, its chosen entry or None while unfinished).
    A step after an unfinished one has entries without overrides or runs."""
    out: list[tuple[Step, list[Entry], Entry | None]] = []
    prior: tuple[str, ...] | None = ()
    chosen: Entry | None = None
    for step in STEPS:
        entries = []
        if not step.chained:
            entries = [Entry(step, c, c.overrides, None) for c in step.candidates]
            entries = [Entry(step, e.candidate, e.overrides, read_archive(e)) for e in entries]
            done = all(e.run is not None for e in entries)
            best = choose({e.candidate.name: e.successes for e in entries}) if done else None
            out.append((step, entries, next((e for e in entries if e.candidate.name == best), None)))
            continue
        if step.default is not None and chosen is None:
            placeholder = Candidate(
                f"(the {[s for s, _, _ in out if s.chained][-1].name} step's choice)",
                f"{step.default} (its run, not rerun)",
            )
            entries.append(Entry(step, placeholder, None, None, carried=True))
        elif step.default is not None and chosen is not None:
            was = chosen.candidate
            carried = Candidate(was.name, f"{step.default} ({was.name}'s run, not rerun)", was.overrides)
            entries.append(Entry(step, carried, chosen.overrides, chosen.run, carried=True))
        for cand in step.candidates:
            entry = Entry(step, cand, None if prior is None else (*prior, *cand.overrides), None)
            run = None if prior is None else read_archive(entry)
            entries.append(Entry(step, cand, entry.overrides, run))
        chosen = None
        if all(e.run is not None for e in entries):
            best = choose({e.candidate.name: e.successes for e in entries})
            chosen = next(e for e in entries if e.candidate.name == best)
        prior = None if chosen is None else chosen.overrides
        out.append((step, entries, chosen))
    return out


def runnable(step_name: str | None, only: list[str] | None) -> list[Entry]:
    """The entries to run now: `only`'s (run again or resumed), else those of `step_name` without an archive,
    else those of the first step with a candidate not run yet. UsageError naming the candidates of the
    earlier steps not run yet when a wanted candidate's step cannot run."""
    steps, todo = plan(), []
    for i, (step, entries, _) in enumerate(steps):
        wanted = [
            e for e in entries if not e.carried and (e.candidate.name in only if only else e.run is None)
        ]
        if step_name not in (None, step.name) or not wanted:
            continue
        if wanted[0].overrides is None:
            missing = [
                e.candidate.name
                for s, es, _ in steps[:i]
                if s.chained
                for e in es
                if e.run is None and not e.carried
            ]
            raise UsageError(
                f"step {step.name} runs once the steps before it have finished; not run yet: {', '.join(missing)}"
            )
        todo += wanted
        if step_name is None and not only:
            break  # the next step's overrides wait for this one's choice
    return todo


def run_candidate(entry: Entry) -> Path:
    """Run (or resume) `entry`'s experiment in runs/tune-ft/<name>, archive it to docs/records/tune-ft/<name>
    and write docs/tuning/finetune/<name>.json from the archive; returns the record's path."""
    name, t0 = entry.candidate.name, time.time()
    run_experiment(entry.command, ROOT)
    run = archived_run(entry.command, ROOT, archive_path(name))
    record = {"step": entry.step.name, "archive": f"docs/records/tune-ft/{name}"}
    overrides = list(entry.overrides or ())
    record |= candidate_record(run, name, entry.candidate.change, overrides, entry.command)
    record["wall_s_this_call"] = round(time.time() - t0, 1)
    write_record(result_path(name), record)
    return result_path(name)


def term_scale(run: FinishedRun, gaze: bool) -> tuple[float | None, float]:
    """(weight x gaze KL, action loss) of the last logged training record, mean over `run`'s training runs;
    the first None without the gaze term. UsageError naming the metrics file that lacks them."""
    terms, actions = [], []
    for rid in run.runs:
        records = [r for r in run.metrics(rid) if "loss/action" in r]
        if not records or (gaze and not {"loss/gaze_kl", "gaze/weight"} <= set(records[-1])):
            needs = "loss/action, loss/gaze_kl and gaze/weight" if gaze else "loss/action"
            raise UsageError(f"{run.metrics_file(rid)}: no training record with {needs}")
        actions.append(float(records[-1]["loss/action"]))
        if gaze:
            terms.append(float(records[-1]["gaze/weight"]) * float(records[-1]["loss/gaze_kl"]))
    mean = sum(terms) / len(terms) if terms else None
    return mean, sum(actions) / len(actions)


def attention_fit(run: FinishedRun) -> str:
    """How close the trained attention is to the gaze prior on held-out frames (the alignment stage, the query
    set the run trained; mean over its training runs): correlation and KL(gaze || attention) in nats."""
    fits = list(run.stage_outputs().alignment.values())
    if not fits:
        return ""
    cc, kl = (sum(float(f[k]) for f in fits) / len(fits) for k in ("gaze_cc", "gaze_kl"))
    return f"CC {cc:.2f}, KL {kl:.2f}"


def row(entry: Entry) -> list[str]:
    """The table row of `entry`."""
    name, change = entry.candidate.name, entry.candidate.change
    if entry.run is None:
        return [entry.step.name, name, change, "not run yet", "", "", "", ""]
    val = validation_successes(entry.run.episodes())
    term, action = term_scale(entry.run, entry.step.arm == "gaze")
    ratio = "no gaze term" if term is None else f"{term:.3g} ({term / action:.3g} x action)"
    fit = attention_fit(entry.run)
    return [entry.step.name, name, change, rate_text(val), per_task_text(val), ratio, f"{action:.3g}", fit]


def choices(steps: list[tuple[Step, list[Entry], Entry | None]]) -> list[str]:
    """The chosen candidate per finished step and, once every step has, the flags the study uses."""
    lines = ["", "Chosen (the most validation successes, ties to the earlier candidate):", ""]
    for step, _, chosen in steps:
        pick = "not yet" if chosen is None else f"**{chosen.candidate.name}**, {chosen.candidate.change}"
        lines.append(f"- {step.name}: {pick}")
    every_arm = next(chosen for step, _, chosen in steps if step.name == "generalist")
    last = steps[-1][2]
    if last is not None and every_arm is not None and last.overrides is not None:
        flags, gaze = every_arm.overrides or (), last.overrides[len(every_arm.overrides or ()) :]
        lines += [
            "",
            f"**Final choice**: recipe and generalist `{shlex.join(flags) or 'the preset, no override'}` (every arm); "
            f"gaze term `{shlex.join(gaze) or 'the defaults, no override'}` (the gaze arm).",
        ]
    return lines


def table() -> str:
    """docs/tuning/finetune.md: every candidate of the protocol, from its archive, in the protocol's order."""
    steps = plan()
    lines = [
        "# Gaze-term tuning for fine-tuning on validation setups",
        "",
        "Written by `python scripts/tune_finetune.py --table` (its docstring states the protocol, fixed on",
        "2026-11-27 before any result); each row is one candidate's `gazereg experiment` run on Meta-World",
        "setups 1300..1319 of ML45's held-out tasks, recounted from its archive in docs/records/tune-ft/ (its",
        "command in docs/tuning/finetune/<candidate>.json). Gaze scale: the gaze weight times the final",
        "training gaze KL, and its ratio to the final training action loss. Attention vs gaze: the trained",
        "attention of the query set the run regularized (the action queries unless the row says otherwise)",
        "against the gaze prior on held-out frames, correlation and KL(gaze || attention) in nats (a baseline",
        "row: the attention it learned without the term). The recipe-scratch rows train the same",
        "policy from random weights (`ml45_scratch`); g-continued fine-tunes the longer-pretrained generalist",
        "(`gazereg pretrain --preset ml45_continued`); the rows after it, the generalist step's choice; the",
        "rows before it, the committed one.",
        "",
    ]
    header = (
        "step", "candidate", "change", "validation success", "per task", "gaze scale", "action loss",
        "attention vs gaze",
    )  # fmt: skip
    lines += markdown_table(header, [row(e) for _, entries, _ in steps for e in entries])
    return "\n".join(lines + choices(steps)) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--step", choices=[s.name for s in STEPS], help="run this step's candidates not yet run")
    p.add_argument("--only", nargs="+", choices=NAMES, help="run (or resume) these candidates")
    p.add_argument("--table", action="store_true", help="only rewrite docs/tuning/finetune.md")
    a = p.parse_args(argv)
    try:
        while not a.table and (todo := runnable(a.step, a.only)):
            for entry in todo:
                print(f"candidate {entry.candidate.name}: {shlex.join(entry.command)}", flush=True)
                run_candidate(entry)
                atomic_write_text(DOCS / "finetune.md", table())
            if a.only:
                break
        DOCS.mkdir(parents=True, exist_ok=True)
        atomic_write_text(DOCS / "finetune.md", table())
    except UsageError as e:
        print(f"{Path(__file__).name}: error: {e}", file=sys.stderr)
        return 2
    print(table())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
