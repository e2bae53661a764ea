"""The experiment's numbers: success tables with Wilson intervals, paired tests, distances (the convergence
analysis is `report.convergence`).

Everything is computed from the experiment's own records (evaluation episodes, training metrics); no number
is typed in. Arms trained with several seeds are pooled over seeds (their evaluation episodes pair by
training seed, task and setup seed).
"""

from __future__ import annotations

import math
import os
import platform
import statistics
from collections import defaultdict
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any, Literal

import torch

from gazereg.evaluation.stats import (
    fisher_exact,
    holm,
    mcnemar_exact,
    paired_mean_difference,
    paired_rate_difference,
    unit_mean_difference,
    wilson,
)
from gazereg.report.ids import RunId
from gazereg.runtime.hardware import BF16_CPU_FLAGS, NumericsKey, cpu_flags, cpu_identity
from gazereg.training.numerics import TrainingAttempt


def run_of(record: dict[str, Any]) -> RunId:
    """The run an evaluation record belongs to (its `"arm"` field)."""
    return RunId.parse(record["arm"])


def success_table(records: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, Any]]]:
    """{arm: {condition: {successes, n, rate, ci95, per_task: {...}}}} pooled over training seeds."""
    cells: dict[tuple[str, str, str], list[bool]] = defaultdict(list)
    for r in records:
        cells[(run_of(r).arm, r["condition"], r["task"])].append(bool(r["success"]))
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for (arm, cond, task), xs in sorted(cells.items()):
        c = out.setdefault(arm, {}).setdefault(cond, {"successes": 0, "n": 0, "per_task": {}})
        c["successes"] += sum(xs)
        c["n"] += len(xs)
        c["per_task"][task] = {"successes": sum(xs), "n": len(xs), "ci95": list(wilson(sum(xs), len(xs)))}
    for arm in out.values():
        for c in arm.values():
            c["rate"] = c["successes"] / c["n"]
            c["ci95"] = list(wilson(c["successes"], c["n"]))
    for (arm, cond), clean_rate in _clean_rates(records).items():
        out[arm][cond]["drop_from_clean"] = clean_rate - out[arm][cond]["rate"]
    return out


def _clean_rates(records: list[dict[str, Any]]) -> dict[tuple[str, str], float]:
    """{(arm, condition): the arm's clean success rate on that condition's setups (training seed, task, setup
    seed)} for the arms evaluated clean: a condition run on fewer setups than clean (an evaluation's
    robustness_episodes) is compared with clean on the same ones."""
    by: dict[tuple[str, str], list[tuple[int, str, int]]] = defaultdict(list)
    clean: dict[tuple[str, int, str, int], bool] = {}
    for r in records:
        run = run_of(r)
        by[(run.arm, r["condition"])].append((run.seed, r["task"], r["seed"]))
        if r["condition"] == "clean":
            clean[(run.arm, run.seed, r["task"], r["seed"])] = bool(r["success"])
    out = {}
    for (arm, cond), keys in by.items():
        same = [clean[(arm, *k)] for k in keys if (arm, *k) in clean]
        if same:
            out[(arm, cond)] = sum(same) / len(same)
    return out


def per_seed_table(records: list[dict[str, Any]]) -> dict[str, dict[str, list[int]]]:
    """{arm@seed: {condition: [successes, n]}} over tasks: how consistent an effect is across training seeds
    (the episodes of one training seed are not independent of each other; seeds are)."""
    out: dict[str, dict[str, list[int]]] = {}
    for r in records:
        cell = out.setdefault(str(run_of(r)), {}).setdefault(r["condition"], [0, 0])
        cell[0] += int(bool(r["success"]))
        cell[1] += 1
    return dict(sorted(out.items()))


def paired_name(arm: str, reference: str, condition: str) -> str:
    """A paired comparison's name, its key in report.json's "paired" tables: "arm vs reference | condition"."""
    return f"{arm} vs {reference} | {condition}"


def split_paired_name(name: str) -> tuple[str, str, str]:
    """(arm, reference, condition) of a `paired_name`."""
    comparison, bar, condition = name.partition(" | ")
    arm, vs, reference = comparison.partition(" vs ")
    if not (bar and vs):
        raise ValueError(f"{name!r} is not a paired comparison's name ('arm vs reference | condition')")
    return arm, reference, condition


def paired_by_setup(
    records: list[dict[str, Any]], value: Callable[[dict[str, Any]], Any], reference: str
) -> Iterator[tuple[str, str, list[Any], list[Any]]]:
    """For each arm but `reference` and each condition both have: (name "arm vs reference | condition", arm,
    the arm's values, the reference's values) on the episodes they share, paired by (training seed, task,
    setup seed). `value(record)` is what is compared; records where it is None are left out."""
    by: dict[tuple[str, str], dict[tuple[int, str, int], Any]] = defaultdict(dict)
    for r in records:
        v = value(r)
        if v is not None:
            run = run_of(r)
            by[(run.arm, r["condition"])][(run.seed, r["task"], r["seed"])] = v
    for arm in sorted({a for a, _ in by} - {reference}):
        for (a, cond), xs in by.items():
            ref = by.get((reference, cond))
            if a != arm or not ref:
                continue
            common = sorted(set(xs) & set(ref))
            if common:
                yield (
                    paired_name(arm, reference, cond),
                    arm,
                    [xs[k] for k in common],
                    [ref[k] for k in common],
                )


def paired_tests(records: list[dict[str, Any]], reference: str = "baseline") -> dict[str, dict[str, Any]]:
    """Each arm against `reference` per condition: exact McNemar on episodes paired by (training seed, task,
    setup seed), Fisher's exact test on the pooled counts, and the paired success-rate difference (arm minus
    reference) with its 95% interval (`stats.paired_rate_difference`)."""
    out = {}
    for name, arm, x, y in paired_by_setup(records, lambda r: bool(r["success"]), reference):
        m, d = mcnemar_exact(x, y), paired_rate_difference(x, y)
        out[name] = {
            "pairs": len(x),
            f"{arm}_only": m["a_only"],
            f"{reference}_only": m["b_only"],
            "mcnemar_p": m["p_value"],
            "fisher_p": fisher_exact(sum(x), len(x), sum(y), len(y)),
            "rate_diff": d["diff"],
            "rate_ci95": d["ci95"],
        }
    return out


def per_task_paired_tests(
    records: list[dict[str, Any]], reference: str = "baseline"
) -> dict[str, dict[str, dict[str, Any]]]:
    """`paired_tests` within each task: {comparison name: {task: its test plus `holm_p`}}, the McNemar p
    adjusted by Holm over the comparison's tasks (a task-by-task reading looks at every task, so one task's
    small p is read against the family). Tasks in the records' order."""
    by_task: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in records:
        by_task[r["task"]].append(r)
    out: dict[str, dict[str, dict[str, Any]]] = defaultdict(dict)
    for task, rows in by_task.items():
        for name, test in paired_tests(rows, reference).items():
            out[name][task] = test
    for tests in out.values():
        for test, p in zip(tests.values(), holm([t["mcnemar_p"] for t in tests.values()]), strict=True):
            test["holm_p"] = p
    return dict(out)


Unit = Literal["seed", "task"]
"""what a unit-level test takes as its sample: the training seed, or the task"""


def unit_level_tests(
    records: list[dict[str, Any]],
    unit: Unit = "seed",
    reference: str = "baseline",
    value: Callable[[dict[str, Any]], float | None] = lambda r: float(bool(r["success"])),
) -> dict[str, dict[str, Any]]:
    """Each arm against `reference` per condition with the `unit` (training seed, or task) as the sample: the
    mean paired difference of `value(record)` (default: success, so a success-rate difference) within each
    unit (episodes paired by training seed, task and setup seed; records whose value is None left out), then
    `stats.unit_mean_difference` over the units, each result with its sorted "units". Comparisons that share
    fewer than two units are left out. Unlike `paired_tests`, which pools every episode, this lets seeds (or
    tasks) disagree: their spread widens the interval."""

    def unit_and_value(r: dict[str, Any]) -> tuple[int | str, float] | None:
        v = value(r)
        return None if v is None else (run_of(r).seed if unit == "seed" else r["task"], v)

    out = {}
    for name, _, x, y in paired_by_setup(records, unit_and_value, reference):
        by_unit: dict[int | str, list[float]] = defaultdict(list)
        for (u, a), (_, b) in zip(x, y):
            by_unit[u].append(a - b)
        if len(by_unit) >= 2:
            units = sorted(by_unit)
            diffs = [sum(by_unit[u]) / len(by_unit[u]) for u in units]
            out[name] = {"units": units, **unit_mean_difference(diffs)}
    return out


def distance_value(key: str = "min_distance") -> Callable[[dict[str, Any]], float | None]:
    """A record's per-episode distance `key` (metres), None where it was not recorded."""
    return lambda r: float(r[key]) if key in r else None


def distance_table(records: list[dict[str, Any]], key: str = "min_distance") -> dict[str, dict[str, Any]]:
    """{arm: {condition: {mean, ci95, n}}} of a per-episode progress measure `key` (min_distance: metres;
    max_reward: a staged reward, `gazereg.report.progress`) pooled over training seeds and tasks
    (normal-approximation interval from the sample SD, as `stats.paired_mean_difference`); empty when the
    records carry none (a simulator without that measure)."""
    cells: dict[tuple[str, str], list[float]] = defaultdict(list)
    for r in records:
        if key in r:
            cells[(run_of(r).arm, r["condition"])].append(float(r[key]))
    out: dict[str, dict[str, Any]] = {}
    for (arm, cond), xs in sorted(cells.items()):
        mean, sd = sum(xs) / len(xs), statistics.stdev(xs) if len(xs) > 1 else 0.0
        half = 1.959964 * sd / math.sqrt(len(xs))
        out.setdefault(arm, {})[cond] = {"mean": mean, "ci95": [mean - half, mean + half], "n": len(xs)}
    return out


def paired_distance_tests(
    records: list[dict[str, Any]], key: str = "min_distance", reference: str = "baseline"
) -> dict[str, dict[str, Any]]:
    """Each arm against `reference` per condition on a per-episode progress measure `key` (`distance_table`),
    paired by (training seed, task, setup seed): mean difference (for a distance, negative: closer than the
    reference), 95% interval, permutation p."""
    pairs = paired_by_setup(records, distance_value(key), reference)
    return {name: paired_mean_difference(x, y) for name, _, x, y in pairs}


def overlap(a: list[float], b: list[float]) -> bool:
    return a[0] <= b[1] and b[0] <= a[1]


def unit_clause(test: dict[str, Any], unit: Unit) -> str:
    """One sentence on a `unit_level_tests` result: the mean of the per-unit (seed or task) differences, its t
    interval, how many units point each way, and whether they settle it."""
    lo, hi = test["ci95"]
    n, units = test["n"], f"{unit}s"
    agree = "excludes 0" if lo > 0 or hi < 0 else f"includes 0: the {units} do not settle it"
    return (
        f" {unit.capitalize()} level ({n} {units}): mean {test['mean_diff']:+.2f}, "
        f"t 95% CI [{lo:+.2f}, {hi:+.2f}], "
        f"{test['above']} of {n} above 0 and {test['below']} below, sign-flip p = {test['sign_flip_p']:.2f} "
        f"(the smallest {n} {units} can give: {test['p_floor']:.2f}); the interval {agree}."
    )


def verdict(
    success: dict[str, Any],
    reference: str = "baseline",
    paired: dict[str, dict[str, Any]] | None = None,
    alpha: float = 0.05,
    levels: dict[Unit, dict[str, dict[str, Any]]] | None = None,
) -> list[str]:
    """Plain sentences on what the data allow one to conclude: with `paired_tests`' results, the paired exact
    test on the shared setups decides (at `alpha`), and a sentence whose test does not reach `alpha` says so
    when the paired difference's approximate interval excludes 0 all the same; without, only non-overlapping Wilson intervals do. With
    `levels` ({unit: `unit_level_tests`' results}, for several training seeds or tasks), each sentence also
    says whether the seeds (tasks) settle it."""
    if reference not in success:
        return ["No baseline arm: no comparison."]
    out = []
    for arm in success:
        if arm == reference:
            continue
        for cond, c in success[arm].items():
            r = success[reference][cond]
            diff = c["rate"] - r["rate"]
            head = f"- {arm} vs {reference}, {cond}: {c['rate']:.2f} vs {r['rate']:.2f} ({diff:+.2f})"
            apart = not overlap(c["ci95"], r["ci95"])
            intervals = "the 95% intervals do not overlap" if apart else "the 95% intervals overlap"
            better = "better" if diff > 0 else "worse"
            name = paired_name(arm, reference, cond)
            test = (paired or {}).get(name)
            tail = "".join(
                unit_clause(tests[name], unit) for unit, tests in (levels or {}).items() if name in tests
            )
            if test is not None:
                p = test["mcnemar_p"]
                if "rate_ci95" in test:
                    lo, hi = test["rate_ci95"]
                    head += f", paired difference 95% CI [{lo:+.2f}, {hi:+.2f}]"
                if p < alpha:
                    out.append(
                        f"{head}; paired McNemar p = {p:.3g} < {alpha}: {arm} is {better} ({intervals}).{tail}"
                    )
                elif "rate_ci95" in test and (test["rate_ci95"][0] > 0 or test["rate_ci95"][1] < 0):
                    out.append(
                        f"{head}; paired McNemar p = {p:.3g} >= {alpha}: not shown at this budget, although the "
                        f"paired difference's approximate 95% CI excludes 0 (the exact test decides; {intervals}).{tail}"
                    )
                else:
                    out.append(
                        f"{head}; paired McNemar p = {p:.3g}: no difference shown at this budget ({intervals}).{tail}"
                    )
            elif apart:
                out.append(f"{head}; {intervals}: {arm} is {better}.")
            else:
                out.append(f"{head}; {intervals}, so this budget does not decide it.")
    return out or [f"Only the {reference} arm ran: no comparison."]


def machine_summary(
    run_precisions: dict[str, str | None] | None = None,
    run_numerics: Mapping[str, Sequence[TrainingAttempt] | None] | None = None,
) -> dict[str, Any]:
    """The machine a report ran on: architecture, cores, torch and Python versions, the GPU's name (or None),
    the CPU's model, torch's CPU capability, the bf16 instruction sets present, and the training's numerics.

    `run_numerics` ({run: the attempts its numerics.json recorded, None for a run that has none}) names the
    machines that trained: where every run recorded one key, "numerics" is that key (not this machine's) and
    "precision" its precision; where they differ, or only some runs recorded one, "numerics" is None; either
    way "trained_on" lists each distinct key with its CPU models and runs (`trained_on`) and
    "unrecorded_runs" the runs (or parts of runs) trained where none was recorded. Where no run recorded a key
    (runs made before numerics.json; None: a report without training) the precision comes from
    `run_precisions` ({run: the precision its config.json records, None where none}): "precision" is the runs'
    one precision (else None) and "numerics" the `NumericsKey.to_dict()` of it on this machine (else None)."""
    runs = dict(run_precisions or {})
    found = set(runs.values())
    precision = found.pop() if len(found) == 1 else None
    recorded = trained_on(run_numerics or {})
    if recorded is None:  # runs made before numerics.json: this machine's key in their precision
        numerics = NumericsKey.here(precision).to_dict() if precision is not None else None
    else:
        keys, unrecorded = recorded
        numerics = keys[0]["numerics"] if len(keys) == 1 and not unrecorded else None
        precision = numerics["precision"] if numerics is not None else None
    return {
        "summary": f"{platform.machine()} CPU, {os.cpu_count()} cores, torch {torch.__version__}, Python {platform.python_version()}",
        "cores": os.cpu_count(),
        "torch": torch.__version__,
        "python": platform.python_version(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "cpu_model": cpu_identity()[1],
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "bf16_isa": sorted(cpu_flags() & BF16_CPU_FLAGS),
        "precision": precision,
        "run_precisions": runs,
        "numerics": numerics,
        **({"trained_on": recorded[0], "unrecorded_runs": recorded[1]} if recorded is not None else {}),
    }


def trained_on(
    run_numerics: Mapping[str, Sequence[TrainingAttempt] | None],
) -> tuple[list[dict[str, Any]], list[str]] | None:
    """(each distinct recorded key as {"numerics": its to_dict(), "cpu_models": [...], "runs": [...]}, in
    the order first met over the runs sorted by name; the runs with an attempt, or with no record, whose key
    is not known), or None when no run recorded any key."""
    keys: dict[NumericsKey, dict[str, Any]] = {}
    unrecorded: list[str] = []
    for run in sorted(run_numerics):
        attempts = run_numerics[run]
        if not attempts or any(a.key is None for a in attempts):
            unrecorded.append(run)
        for a in attempts or ():
            if a.key is not None:
                entry = keys.setdefault(a.key, {"numerics": a.key.to_dict(), "cpu_models": [], "runs": []})
                for name, value in (("cpu_models", a.cpu_model), ("runs", run)):
                    if value is not None and value not in entry[name]:
                        entry[name].append(value)
    return (list(keys.values()), unrecorded) if keys else None
