"""The report's convergence analysis: clean success at each training checkpoint (Wilson intervals), the steps to
a threshold and to the baseline's final success, and a paired bootstrap interval on those steps.

    points = [ConvergencePoint(run, task, setup, success), ...]   # every run names its checkpoint's step
    conv = convergence_report(points, threshold=0.5)              # report.json's "convergence"

The evaluation unit is one episode setup, (training seed, task, setup seed): every arm and every checkpoint
evaluates the same units, so the bootstrap resamples them once for all curves (`stats.bootstrap_steps_to_reach`).
A checkpoint that lacks a unit another one has is refused, never dropped (an arm may have fewer checkpoints).
The units are episodes, not training seeds: like the pooled paired tests, the interval holds each arm's
trained policies fixed.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, NamedTuple

import numpy as np

from gazereg.evaluation.stats import bootstrap_steps_to_reach, steps_to_threshold, wilson
from gazereg.report.ids import RunId

BOOTSTRAP_RESAMPLES = 2000
"""resamples of the convergence bootstrap"""
BOOTSTRAP_SEED = 0
"""seed of the convergence bootstrap's generator: the same records give the same report"""
REFERENCE = "baseline"
"""the arm whose final success rate the others are timed against"""

EvalUnit = tuple[int, str, int]
"""one evaluation unit: (training seed, task, setup seed)"""


class ConvergencePoint(NamedTuple):
    """One clean evaluation episode of a checkpoint."""

    run: RunId
    """the run at its checkpoint (names its training step)"""
    task: str
    setup: int
    """the episode's setup seed"""
    success: bool

    @property
    def unit(self) -> EvalUnit:
        return (self.run.seed, self.task, self.setup)


def _step(run: RunId) -> int:
    if run.step is None:
        raise ValueError(f"run {run} names no training step: a convergence point needs one")
    return run.step


def checkpoint_tally(points: Iterable[ConvergencePoint]) -> dict[str, dict[int, tuple[int, int]]]:
    """{arm: {training step: (successes, episodes)}} pooled over training seeds, tasks and setups; every run
    must name its step. Arms and steps keep the order they first appear in."""
    cells: dict[str, dict[int, list[int]]] = {}
    for p in points:
        cell = cells.setdefault(p.run.arm, {}).setdefault(_step(p.run), [0, 0])
        cell[0] += int(p.success)
        cell[1] += 1
    return {arm: {step: (k, n) for step, (k, n) in pts.items()} for arm, pts in cells.items()}


def convergence(curves: dict[str, dict[int, tuple[int, int]]], threshold: float) -> dict[str, Any]:
    """curves: {arm: {step: (successes, n)}} -> rates, steps to `threshold`, and each arm's steps to reach the
    baseline's final success rate (None when that rate is 0: nothing to reach)."""
    out: dict[str, Any] = {"threshold": threshold, "arms": {}}
    for arm, pts in curves.items():
        steps = sorted(pts)
        rates = [pts[s][0] / pts[s][1] for s in steps]
        out["arms"][arm] = {
            "steps": steps,
            "rates": rates,
            "ci95": [list(wilson(*pts[s])) for s in steps],
            "steps_to_threshold": steps_to_threshold(steps, rates, threshold),
        }
    if REFERENCE in out["arms"] and out["arms"][REFERENCE]["rates"]:
        final = out["arms"][REFERENCE]["rates"][-1]
        out["baseline_final"] = final
        for c in out["arms"].values():
            c["steps_to_baseline_final"] = (
                steps_to_threshold(c["steps"], c["rates"], final) if final > 0 else None
            )
    return out


def _unit_text(unit: EvalUnit) -> str:
    return f"(training seed {unit[0]}, task {unit[1]}, setup seed {unit[2]})"


def checkpoint_outcomes(
    points: Iterable[ConvergencePoint],
) -> tuple[list[EvalUnit], dict[str, tuple[list[int], np.ndarray]]]:
    """(the units, sorted; {arm: (its steps, ascending; bool (checkpoints, units) success)}): every checkpoint's
    outcome on every unit, in the units' order. ValueError naming the arm, step and unit when a checkpoint
    lacks a unit another checkpoint (of any arm) evaluated, or evaluated one twice; an arm may have fewer
    checkpoints than another."""
    cells: dict[str, dict[int, dict[EvalUnit, bool]]] = {}
    for p in points:
        cell = cells.setdefault(p.run.arm, {}).setdefault(_step(p.run), {})
        if p.unit in cell:
            raise ValueError(
                f"convergence: {p.run.arm} at step {p.run.step} evaluated {_unit_text(p.unit)} twice"
            )
        cell[p.unit] = bool(p.success)
    units = sorted({u for by_step in cells.values() for cell in by_step.values() for u in cell})
    out = {}
    for arm, by_step in cells.items():
        steps = sorted(by_step)
        for step in steps:
            missing = [u for u in units if u not in by_step[step]]
            if missing:
                raise ValueError(
                    f"convergence: {arm} at step {step} has no episode for {_unit_text(missing[0])}"
                    f"{f' and {len(missing) - 1} more units' if len(missing) > 1 else ''}, which another "
                    "checkpoint evaluated: the paired bootstrap needs every checkpoint on the same units"
                )
        out[arm] = (steps, np.array([[by_step[s][u] for u in units] for s in steps], dtype=bool))
    return units, out


def convergence_report(
    points: Iterable[ConvergencePoint],
    threshold: float,
    resamples: int = BOOTSTRAP_RESAMPLES,
    seed: int = BOOTSTRAP_SEED,
) -> dict[str, Any]:
    """report.json's "convergence": `convergence` of the points' tally, and (when there are points) its
    "bootstrap": `stats.bootstrap_steps_to_reach` over the evaluation units with the baseline as the
    reference, "to_baseline_final" None when the baseline's final rate is 0 or no baseline ran."""
    points = list(points)
    conv = convergence(checkpoint_tally(points), threshold)
    units, outcomes = checkpoint_outcomes(points)
    if not units:
        return conv
    boot = bootstrap_steps_to_reach(
        {arm: steps for arm, (steps, _) in outcomes.items()},
        {arm: o for arm, (_, o) in outcomes.items()},
        threshold,
        REFERENCE if REFERENCE in outcomes else None,
        resamples,
        seed,
    )
    conv["bootstrap"] = {
        "unit": "(training seed, task, setup seed)",
        "units": boot["units"],
        "resamples": boot["resamples"],
        "seed": boot["seed"],
        "to_threshold": boot["to_threshold"],
        "to_baseline_final": boot["to_reference_final"],
    }
    return conv
