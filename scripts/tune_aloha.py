"""Tune the Gym-Aloha training recipe WITHOUT gaze, on validation setups that are neither training nor
evaluation setups (issue 37: the `aloha` preset's baseline and gaze arms both scored 0/100 with LIBERO's
recipe, never tuned on Aloha, so the gaze question cannot be asked there yet).

    bash scripts/aloha_lane.sh --run python scripts/tune_aloha.py                # every candidate not yet run
    bash scripts/aloha_lane.sh --run python scripts/tune_aloha.py --only chunk50-te
    .venv/bin/python scripts/tune_aloha.py --table                               # only docs/tuning/aloha.md

Protocol (fixed on 2026-12-06, before any candidate ran):
- Shared command: `gazereg experiment --preset aloha --arms baseline` (transfer cube and insertion, the preset's
  50 demonstrations per task on setups 0..49 with replacements from 50..69, its 6,000 steps of batch 32,
  training seed 0; `--threads-per-run 2`, an execution key, so that the one arm uses both cores), validated
  on setups 2000..2024 of each task (`--eval.seed-start 2000 --eval.episodes 25`, the env's 400 steps, clean):
  50 episodes a candidate. The evaluation's setups are 1000..1049 and the held-out demonstrations' (attention
  alignment and held-out loss only) 2500..2501: all disjoint.
- Candidates change one thing against `default` (the preset), in the order of how much each was expected to
  matter. The preset predicts a chunk of 4 actions (0.08 s at 50 Hz) every step and executes its first; ACT
  (Zhao et al., 2023), the policy these tasks were made for, predicts chunks of 100 steps and found chunking
  the change that mattered most on them: `chunk50-te` (chunks of 50, a chunk every step, the actions for now
  averaged with ACT's weights exp(-0.01 i)), `chunk50-open` (chunks of 50, the first 25 executed open loop),
  `chunk16-te` (chunks of 16, averaged), then `steps12k` (12,000 steps) and `lr5e-4` (learning rate 5e-4).
- Choice: the most validation successes over both tasks; ties (at the floor every candidate has 0) go to the
  larger sum over episodes of the highest staged reward an episode reached (Gym-Aloha's 0..4: transfer cube 1
  touched, 2 lifted, 3 both grippers on it, 4 handed over; insertion 1 one touched, 2 both grasped, 3 peg
  against socket, 4 inserted), then to the earlier candidate. The chosen flags then go into every arm's
  recipe of the `aloha` preset (baseline, gaze, uniform); the gaze term is not retuned here. A second round,
  if any, is stated here before it runs.
- Amended on 2026-12-06, with two candidates archived and none chosen, changing no candidate's configuration
  (tested): each command pins the preset's values, as they were, of the keys the candidates change and of the
  validation conditions (`PINNED`), so the archives still check against their commands after the preset has
  taken the choice.
The later candidates copy the first's demonstrations (`--data-from`, when its folder is here). Each finished
candidate `runs/tune-aloha/<name>` is archived as docs/records/tune-aloha/<name> (`gazereg archive`, so its row
recomputes from its episodes) and recorded in docs/tuning/aloha/<name>.json; docs/tuning/aloha.md, the table
of every candidate, is read from the archives.
"""

from __future__ import annotations

import sys
from pathlib import Path

from gazereg.experiment.finished import Record
from gazereg.experiment.tuning import (
    Candidate,
    Protocol,
    markdown_table,
    per_task_text,
    rate_text,
    totals,
    validation_successes,
)
from gazereg.runtime.errors import UsageError

ROOT = Path(__file__).resolve().parents[1]
VALIDATION_FROM = 2000
BASE = (
    "--preset", "aloha", "--arms", "baseline", "--threads-per-run", "2",
    "--eval.seed-start", str(VALIDATION_FROM), "--eval.episodes", "25",
)  # fmt: skip
PINNED = (
    "--train.policy.chunk", "4", "--train.policy.n-action-steps", "1",
    "--train.policy.temporal-ensemble", "None", "--train.steps", "6000", "--train.optim.lr", "0.001",
    "--eval.conditions", "clean", "--eval.robustness-episodes", "None",
)  # fmt: skip
"""the `aloha` preset's recipe and evaluation when the protocol was fixed, for the keys the candidates change"""
STAGES = (1, 2, 3, 4)
"""the staged rewards the table counts episodes reaching"""


def _chunk(k: int, ensemble: bool) -> tuple[str, ...]:
    how = (
        ("--train.policy.temporal-ensemble", "0.01")
        if ensemble
        else ("--train.policy.n-action-steps", str(k // 2))
    )
    return ("--train.policy.chunk", str(k), *how)


PROTOCOL = Protocol(
    "aloha",
    ROOT,
    BASE,
    (
        Candidate("default", "the preset: chunks of 4, one predicted every step, its first action executed"),
        Candidate(
            "chunk50-te", "chunks of 50, one every step, averaged (ACT's exp(-0.01 i))", _chunk(50, True)
        ),
        Candidate("chunk50-open", "chunks of 50, the first 25 executed open loop", _chunk(50, False)),
        Candidate("chunk16-te", "chunks of 16, one every step, averaged", _chunk(16, True)),
        Candidate("steps12k", "12,000 steps", ("--train.steps", "12000")),
        Candidate("lr5e-4", "learning rate 5e-4", ("--train.optim.lr", "5e-4")),
    ),
    pinned=PINNED,
)


def highest_rewards(episodes: list[Record]) -> list[float]:
    """The highest staged reward of each clean episode, in order. UsageError when one has none (evaluated
    before evaluation records carried `max_reward`)."""
    clean = [ep for ep in episodes if ep["condition"] == "clean"]
    if any("max_reward" not in ep for ep in clean):
        raise UsageError("an episode has no max_reward: rerun its evaluation with this gazereg")
    return [float(ep["max_reward"]) for ep in clean]


def stages_text(rewards: list[float]) -> str:
    """ "a / b / c / d" episodes reaching each of `STAGES` (out of all)."""
    return " / ".join(str(sum(r >= s for r in rewards)) for s in STAGES) + f" of {len(rewards)}"


def score(episodes: list[Record]) -> tuple[int, float]:
    """A candidate's score: (its validation successes, the sum of its episodes' highest staged rewards)."""
    return totals(validation_successes(episodes))[0], sum(highest_rewards(episodes))


def chosen() -> Candidate | None:
    """The chosen candidate, from the archives; None while a candidate has not run."""
    return PROTOCOL.chosen_from_archives(score)


def table() -> str:
    """docs/tuning/aloha.md: every candidate, recounted from its archive, in the protocol's order."""
    lines = [
        "# The Gym-Aloha training recipe, tuned without gaze on validation setups",
        "",
        "Written by `python scripts/tune_aloha.py --table` (its docstring states the protocol, fixed on 2026-12-06",
        "before any result); each row is one candidate's `gazereg experiment --preset aloha --arms baseline` run,",
        f"validated on setups {VALIDATION_FROM}..{VALIDATION_FROM + 24} of each task (clean), recounted from its",
        "archive in docs/records/tune-aloha/ (its command in docs/tuning/aloha/<candidate>.json). Stages: episodes",
        "whose highest staged reward reached 1 / 2 / 3 / 4 (4 is success).",
        "",
    ]
    header = ("candidate", "change", "successes", "per task", "stages reached", "summed highest reward")
    rows, scores = [], {}
    for cand in PROTOCOL.candidates:
        run = PROTOCOL.finished(cand)
        if run is None:
            rows.append([cand.name, cand.change, "not run yet", "", "", ""])
            continue
        val, rewards = validation_successes(run.episodes()), highest_rewards(run.episodes())
        scores[cand.name] = score(run.episodes())
        rows.append(
            [
                cand.name,
                cand.change,
                rate_text(val),
                per_task_text(val),
                stages_text(rewards),
                f"{sum(rewards):g}",
            ]
        )
    lines += markdown_table(header, rows)
    lines += PROTOCOL.choice(
        scores, "the most validation successes, then the larger summed highest reward, then the earlier"
    )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    return PROTOCOL.main(argv, table, (__doc__ or "").splitlines()[0])


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
