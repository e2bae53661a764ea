"""Statistics for honest comparisons: Wilson intervals, exact paired and unpaired tests, convergence.

Evaluation arms share their episode seeds, so two policies' outcomes on the same seeds form pairs; the
paired exact test (McNemar's, a binomial test on the discordant pairs) uses that. Fisher's exact test
compares two success counts without pairing; `paired_rate_difference` says how large a paired difference in
success rate is, with an interval. `bootstrap_steps_to_reach` gives the steps a training curve takes to reach
a success rate an interval, resampling the evaluation units every arm and checkpoint share.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np


def wilson(successes: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion (95% by default); (0, 1) when n == 0. Its bounds hold the
    rate: exactly 0 below when there is no success and exactly 1 above when every trial is one (the formula
    leaves a rounding error there, which would put the rate outside its own interval)."""
    if n < 0 or not 0 <= successes <= n:
        raise ValueError(f"need 0 <= successes <= n, got {successes}/{n}")
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    lo = 0.0 if successes == 0 else max(0.0, centre - half)
    hi = 1.0 if successes == n else min(1.0, centre + half)
    return lo, hi


def binom_two_sided(k: int, n: int, p: float = 0.5) -> float:
    """Exact two-sided binomial test p-value (sum of outcomes no more likely than k)."""
    if n == 0:
        return 1.0
    pmf = [math.comb(n, i) * p**i * (1 - p) ** (n - i) for i in range(n + 1)]
    return min(1.0, sum(q for q in pmf if q <= pmf[k] * (1 + 1e-9)))


def holm(p_values: Sequence[float]) -> list[float]:
    """Holm's step-down adjustment of a family of p-values (a family-wise error rate of alpha when each adjusted
    p is compared with alpha), in the input order: the i-th smallest p times (m - i), made non-decreasing in
    that order and capped at 1."""
    order = sorted(range(len(p_values)), key=lambda i: p_values[i])
    out = [0.0] * len(p_values)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (len(p_values) - rank) * p_values[i]))
        out[i] = running
    return out


def paired_counts(a: Sequence[bool], b: Sequence[bool]) -> tuple[int, int, int, int]:
    """The 2x2 table of two arms' outcomes on the same seeds: (both solved, only a, only b, neither)."""
    if len(a) != len(b):
        raise ValueError(f"paired outcomes must have equal length, got {len(a)} and {len(b)}")
    both = sum(1 for x, y in zip(a, b) if x and y)
    a_only = sum(1 for x, y in zip(a, b) if x and not y)
    b_only = sum(1 for x, y in zip(a, b) if y and not x)
    return both, a_only, b_only, len(a) - both - a_only - b_only


def mcnemar_exact(a: Sequence[bool], b: Sequence[bool]) -> dict[str, float]:
    """Paired exact test of two arms' outcomes on the same seeds.

    Returns {"a_only": episodes only a solved, "b_only": only b solved, "p_value": two-sided}."""
    _, a_only, b_only, _ = paired_counts(a, b)
    return {"a_only": a_only, "b_only": b_only, "p_value": binom_two_sided(a_only, a_only + b_only)}


def mcnemar_power(a_only_rate: float, b_only_rate: float, pairs: int, alpha: float = 0.05) -> float:
    """Probability that `mcnemar_exact` on `pairs` pairs reaches p < alpha when each pair is, independently,
    solved only by a with probability `a_only_rate` and only by b with `b_only_rate` (the discordant-pair
    rates a previous comparison measured). Exact: sums over the number of discordant pairs and their split."""
    discordant = a_only_rate + b_only_rate
    if not (a_only_rate >= 0 and b_only_rate >= 0 and 0 < discordant <= 1) or pairs < 0:
        raise ValueError(
            f"need rates >= 0 with 0 < sum <= 1 and pairs >= 0, got {a_only_rate}, {b_only_rate}, {pairs}"
        )
    share = a_only_rate / discordant
    power = 0.0
    for d in range(pairs + 1):
        weight = math.comb(pairs, d) * discordant**d * (1 - discordant) ** (pairs - d)
        if weight < 1e-15:
            continue
        significant = (k for k in range(d + 1) if binom_two_sided(k, d) < alpha)
        power += weight * sum(math.comb(d, k) * share**k * (1 - share) ** (d - k) for k in significant)
    return power


def pairs_for_power(
    a_only_rate: float, b_only_rate: float, power: float = 0.8, alpha: float = 0.05, limit: int = 5000
) -> int:
    """The fewest pairs with `mcnemar_power` >= power (ValueError past `limit`)."""
    for n in range(1, limit + 1):
        if mcnemar_power(a_only_rate, b_only_rate, n, alpha) >= power:
            return n
    raise ValueError(f"more than {limit} pairs needed for power {power} at these rates")


def pairs_for_power_normal(
    a_only_rate: float, b_only_rate: float, power: float = 0.8, alpha: float = 0.05
) -> float:
    """Pairs a two-sided McNemar test at `alpha` needs for `power`, by the normal approximation (Connor 1987):
    (z_alpha/2 sqrt(d) + z_power sqrt(d - e^2))^2 / e^2 with d the discordant rate and e the rates'
    difference; inf when the rates are equal. Quick where the exact `pairs_for_power` would scan thousands."""
    from statistics import NormalDist

    d, e = a_only_rate + b_only_rate, a_only_rate - b_only_rate
    if not (a_only_rate >= 0 and b_only_rate >= 0 and 0 < d <= 1):
        raise ValueError(f"need rates >= 0 with 0 < sum <= 1, got {a_only_rate}, {b_only_rate}")
    if e == 0:
        return math.inf
    z = NormalDist()
    root = z.inv_cdf(1 - alpha / 2) * math.sqrt(d) + z.inv_cdf(power) * math.sqrt(d - e * e)
    return root * root / (e * e)


def paired_rate_difference(a: Sequence[bool], b: Sequence[bool], z: float = 1.959964) -> dict[str, Any]:
    """Difference of two success rates on the same seeds, rate(a) - rate(b), with Newcombe's (1998, method 10)
    95% interval for paired proportions: the two Wilson intervals combined with the pairs' phi correlation.
    Unlike a Wald interval it stays inside [-1, 1] and keeps its coverage near 0 or 1 and with few pairs.

    Returns {"n": pairs, "diff": rate(a) - rate(b), "ci95": [low, high]}."""
    both, a_only, b_only, neither = paired_counts(a, b)
    n = len(a)
    if n == 0:
        raise ValueError("no pairs to compare")
    pa, pb = (both + a_only) / n, (both + b_only) / n
    (la, ua), (lb, ub) = wilson(both + a_only, n, z), wilson(both + b_only, n, z)
    margins = (both + a_only) * (b_only + neither) * (both + b_only) * (a_only + neither)
    phi = (both * neither - a_only * b_only) / math.sqrt(margins) if margins else 0.0
    diff = pa - pb
    down = math.sqrt(max(0.0, (pa - la) ** 2 - 2 * phi * (pa - la) * (ub - pb) + (ub - pb) ** 2))
    up = math.sqrt(max(0.0, (ua - pa) ** 2 - 2 * phi * (ua - pa) * (pb - lb) + (pb - lb) ** 2))
    return {"n": n, "diff": diff, "ci95": [max(-1.0, diff - down), min(1.0, diff + up)]}


def fisher_exact(k1: int, n1: int, k2: int, n2: int) -> float:
    """Two-sided Fisher exact test p-value for successes k1/n1 vs k2/n2."""
    total_k, total = k1 + k2, n1 + n2

    def prob(x: int) -> float:
        return math.comb(n1, x) * math.comb(n2, total_k - x) / math.comb(total, total_k)

    lo, hi = max(0, total_k - n2), min(n1, total_k)
    p_obs = prob(k1)
    return min(1.0, sum(prob(x) for x in range(lo, hi + 1) if prob(x) <= p_obs * (1 + 1e-9)))


def paired_mean_difference(
    a: Sequence[float], b: Sequence[float], permutations: int = 20_000, seed: int = 0
) -> dict[str, float]:
    """Paired comparison of a continuous outcome (e.g. distance to the goal) on the same seeds.

    Returns the means, the mean difference a - b with a normal-approximation 95% interval, and a two-sided
    sign-flip permutation p-value (seeded, so reproducible; (hits + 1) / (permutations + 1))."""

    x, y = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 1:
        raise ValueError(f"paired outcomes must be two equal-length lists, got {x.shape} and {y.shape}")
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise ValueError("paired outcomes must be finite")
    n = len(x)
    if n == 0:
        raise ValueError("no pairs to compare")
    d = x - y
    mean = float(d.mean())
    half = 1.959964 * float(d.std(ddof=1)) / math.sqrt(n) if n > 1 else float("inf")
    signs = np.random.default_rng(seed).choice([-1.0, 1.0], size=(permutations, n))
    null = np.abs((signs * d).mean(axis=1))
    p = (int((null >= abs(mean) - 1e-12).sum()) + 1) / (permutations + 1)
    return {
        "n": n,
        "mean_a": float(x.mean()),
        "mean_b": float(y.mean()),
        "mean_diff": mean,
        "ci95": [mean - half, mean + half],
        "p_value": min(1.0, p),
    }


def steps_to_threshold(steps: Sequence[int], values: Sequence[float], threshold: float) -> int | None:
    """First step at which a success-versus-steps curve reaches `threshold`; None if it never does."""
    for s, v in zip(steps, values):
        if v >= threshold:
            return int(s)
    return None


def student_t_cdf(t: float, df: int) -> float:
    """P(T <= t) for Student's t with `df` (an integer >= 1) degrees of freedom, from the exact finite sums
    for integer df (Abramowitz and Stegun 26.7.3 and 26.7.4)."""
    if df < 1:
        raise ValueError(f"Student's t needs df >= 1, got {df}")
    theta = math.atan(abs(t) / math.sqrt(df))
    s, c2 = math.sin(theta), math.cos(theta) ** 2
    if df % 2:  # odd df: (2 / pi) * (theta + sin * cos * (1 + 2/3 cos^2 + 2*4/(3*5) cos^4 + ...))
        term, total = 1.0, 1.0 if df > 1 else 0.0
        for k in range(1, (df - 1) // 2):
            term *= 2 * k / (2 * k + 1) * c2
            total += term
        inside = 2 / math.pi * (theta + s * math.cos(theta) * total)
    else:  # even df: sin * (1 + 1/2 cos^2 + 1*3/(2*4) cos^4 + ...)
        term, total = 1.0, 1.0
        for k in range(1, df // 2):
            term *= (2 * k - 1) / (2 * k) * c2
            total += term
        inside = s * total
    return 0.5 + math.copysign(0.5 * inside, t)


def student_t_quantile(p: float, df: int) -> float:
    """The t with `student_t_cdf(t, df) == p`, 0 < p < 1 (bisection to 1e-12)."""
    if not 0 < p < 1:
        raise ValueError(f"a quantile needs 0 < p < 1, got {p}")
    lo, hi = -1.0, 1.0
    while student_t_cdf(lo, df) > p:
        lo *= 2
    while student_t_cdf(hi, df) < p:
        hi *= 2
    while hi - lo > 1e-12 * max(1.0, abs(hi)):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if student_t_cdf(mid, df) < p else (lo, mid)
    return (lo + hi) / 2


def unit_mean_difference(diffs: Sequence[float]) -> dict[str, Any]:
    """Inference with a unit of replication (a training seed, or a task) as the sample: `diffs` holds one mean
    paired difference (arm minus reference: a success rate, or a distance) per unit. Returns their count `n`,
    their mean, a Student-t 95% interval (n - 1 df), how many units are above and below zero, and the exact
    two-sided sign-flip p-value over all 2^n sign patterns, whose floor (`p_floor`, 2 / 2^n when no difference
    is 0) says how small a p-value this many units can give."""
    d = np.asarray(diffs, dtype=np.float64)
    if d.ndim != 1 or len(d) < 2:
        raise ValueError(f"a unit-level comparison needs at least two units (seeds or tasks), got {len(d)}")
    if not np.isfinite(d).all():
        raise ValueError("per-unit differences must be finite")
    n, mean = len(d), float(d.mean())
    half = student_t_quantile(0.975, n - 1) * float(d.std(ddof=1)) / math.sqrt(n)
    signs = np.array(np.meshgrid(*[[-1.0, 1.0]] * n)).reshape(n, -1).T
    null = np.abs((signs * d).mean(axis=1))
    return {
        "n": n,
        "diffs": [float(x) for x in d],
        "mean_diff": mean,
        "ci95": [mean - half, mean + half],
        "above": int((d > 0).sum()),
        "below": int((d < 0).sum()),
        "sign_flip_p": float((null >= abs(mean) - 1e-12).mean()),
        "p_floor": float((null >= null.max() - 1e-12).mean()),
    }


def resample_counts(units: int, resamples: int, seed: int) -> np.ndarray:
    """How often each of `units` evaluation units is drawn in each bootstrap resample: `units` draws with
    replacement per resample, from numpy's default Generator seeded with `seed` (so the same seed gives the
    same resamples).

    Returns int64 (1 + resamples, units): row 0 is the sample itself (every unit once), rows 1.. the resamples.
    Applying one row to several curves at once is what keeps them paired."""
    if units < 1 or resamples < 1:
        raise ValueError(f"a bootstrap needs units >= 1 and resamples >= 1, got {units} and {resamples}")
    draws = np.random.default_rng(seed).integers(0, units, size=(resamples, units))
    flat = (draws + units * np.arange(resamples)[:, None]).ravel()
    counts = np.bincount(flat, minlength=resamples * units).reshape(resamples, units)
    return np.vstack([np.ones((1, units), dtype=np.int64), counts.astype(np.int64)])


def first_crossings(steps: Sequence[int], reached: np.ndarray) -> np.ndarray:
    """The first step of each row's curve that is at or above its target.

    `reached`: bool (rows, checkpoints), whether the curve is at or above the target at each checkpoint of
    `steps` (training steps, ascending). Returns float64 (rows,): that step, `inf` where no checkpoint is."""
    s = np.asarray(steps, dtype=np.float64)
    if reached.ndim != 2 or reached.shape[1] != len(s):
        raise ValueError(f"reached must be (rows, {len(s)} checkpoints), got {reached.shape}")
    return np.where(reached.any(axis=1), s[reached.argmax(axis=1)], np.inf)


def _step_or_none(x: float) -> int | None:
    return None if math.isinf(x) else int(x)


def _percentiles(values: np.ndarray) -> list[int | None]:
    """[2.5th, 97.5th] percentile (inverted CDF, so each is one of `values`) of steps, float64 with `inf` for
    "not reached" (sorted last, returned as None)."""
    lo, hi = np.quantile(values, [0.025, 0.975], method="inverted_cdf")
    return [_step_or_none(float(lo)), _step_or_none(float(hi))]


def crossing_summary(crossings: np.ndarray, reference: np.ndarray | None = None) -> dict[str, Any]:
    """A first crossing and its bootstrap distribution. `crossings`: float64 (1 + resamples,) steps, row 0
    the sample's own, `inf` = not reached (as `first_crossings` returns them).

    Returns {"steps": the sample's crossing (None: not reached), "ci95": [2.5th, 97.5th percentile] of the
    resamples' (None for a percentile that is "not reached"), "reached": the share of resamples with a
    crossing}; with `reference` (another curve's crossings, the same shape and resamples) also
    "minus_reference": {"steps": the sample's difference in steps (None unless both cross), "ci95": its
    percentiles over the resamples in which both cross (None if none does), "both_reached": their share}."""
    boot = crossings[1:]
    out: dict[str, Any] = {
        "steps": _step_or_none(float(crossings[0])),
        "ci95": _percentiles(boot),
        "reached": float(np.isfinite(boot).mean()),
    }
    if reference is not None:
        both = np.isfinite(crossings) & np.isfinite(reference)  # row 0: the sample
        diff = np.subtract(crossings, reference, out=np.full_like(crossings, np.inf), where=both)
        out["minus_reference"] = {
            "steps": _step_or_none(float(diff[0])),
            "ci95": _percentiles(diff[1:][both[1:]]) if both[1:].any() else None,
            "both_reached": float(both[1:].mean()),
        }
    return out


def bootstrap_steps_to_reach(
    steps: dict[str, Sequence[int]],
    outcomes: dict[str, np.ndarray],
    threshold: float,
    reference: str | None = None,
    resamples: int = 2000,
    seed: int = 0,
) -> dict[str, Any]:
    """Paired bootstrap of the steps at which success-versus-steps curves first reach a target.

    `outcomes[arm]`: bool (checkpoints, units), the arm's success on each evaluation unit at each of its
    checkpoints `steps[arm]` (training steps, ascending); every arm has the same units in the same column
    order, which pairs them. Each resample (`resample_counts`: units drawn with replacement, `seed`) is applied
    to every arm and checkpoint alike; each curve (success rate = successes / units) is recomputed and its
    first checkpoint at or above the target found (`first_crossings`). Targets: `threshold` (a success rate),
    and the `reference` arm's success rate at its last checkpoint in the same resample (so the reference
    reaches its own final by its last checkpoint in every resample).

    Returns {"units", "resamples", "seed", "to_threshold": {arm: `crossing_summary`}, "to_reference_final":
    {arm: `crossing_summary`} or None (no reference, or its final rate in the sample is 0: nothing to reach)},
    each arm but the reference with its difference from the reference ("minus_reference")."""
    if reference is not None and reference not in outcomes:
        raise ValueError(f"reference arm {reference!r} has no outcomes (arms: {sorted(outcomes)})")
    shapes = {arm: o.shape for arm, o in outcomes.items()}
    units = {shape[1] for shape in shapes.values() if len(shape) == 2}
    if len(units) != 1 or any(len(s) != 2 or s[0] != len(steps[a]) for a, s in shapes.items()):
        raise ValueError(
            f"outcomes must be (checkpoints, units) with one unit count for every arm, got {shapes}"
        )
    n = units.pop()
    counts = resample_counts(n, resamples, seed)
    sums = {arm: counts @ o.astype(np.int64).T for arm, o in outcomes.items()}  # (1 + resamples, checkpoints)
    to_threshold = {arm: first_crossings(steps[arm], s / n >= threshold) for arm, s in sums.items()}
    to_final = None
    if reference is not None and sums[reference][0, -1] > 0:
        final = sums[reference][:, -1:]  # the reference's final successes in each resample
        to_final = {arm: first_crossings(steps[arm], s >= final) for arm, s in sums.items()}

    def summaries(crossings: dict[str, np.ndarray]) -> dict[str, Any]:
        ref = crossings.get(reference) if reference is not None else None
        return {arm: crossing_summary(c, None if arm == reference else ref) for arm, c in crossings.items()}

    return {
        "units": n,
        "resamples": resamples,
        "seed": seed,
        "to_threshold": summaries(to_threshold),
        "to_reference_final": summaries(to_final) if to_final is not None else None,
    }
