import math

import numpy as np
import pytest

from gazereg.evaluation.stats import (
    binom_two_sided,
    fisher_exact,
    mcnemar_exact,
    paired_rate_difference,
    steps_to_threshold,
    wilson,
)


def test_wilson_known_values():
    lo, hi = wilson(8, 20)
    assert lo == pytest.approx(0.2188, abs=1e-3) and hi == pytest.approx(0.6134, abs=1e-3)
    assert wilson(0, 10)[0] == 0.0 and wilson(10, 10)[1] == pytest.approx(1.0)
    assert wilson(0, 0) == (0.0, 1.0)
    with pytest.raises(ValueError):
        wilson(3, 2)


def test_exact_tests():
    assert binom_two_sided(5, 10) == pytest.approx(1.0)
    assert binom_two_sided(0, 10) == pytest.approx(2 / 1024)
    assert fisher_exact(32, 120, 40, 120) == pytest.approx(0.32, abs=0.02)
    assert fisher_exact(10, 10, 0, 10) < 1e-4
    r = mcnemar_exact([1, 1, 0, 0, 1], [1, 0, 0, 1, 0])
    assert r["a_only"] == 2 and r["b_only"] == 1 and r["p_value"] == pytest.approx(1.0)
    with pytest.raises(ValueError):
        mcnemar_exact([1], [1, 0])


def test_steps_to_threshold():
    assert steps_to_threshold([100, 200, 300], [0.1, 0.5, 0.6], 0.5) == 200
    assert steps_to_threshold([100], [0.1], 0.5) is None


def test_paired_mean_difference():
    from gazereg.evaluation.stats import paired_mean_difference

    same = paired_mean_difference([0.1, 0.2, 0.3], [0.1, 0.2, 0.3])
    assert same["mean_diff"] == 0 and same["p_value"] == 1.0
    closer = paired_mean_difference([0.01 * i for i in range(30)], [0.01 * i + 0.05 for i in range(30)])
    assert closer["mean_diff"] == pytest.approx(-0.05) and closer["p_value"] < 0.001
    assert closer["ci95"][0] <= closer["mean_diff"] <= closer["ci95"][1]
    noisy = paired_mean_difference([0.1, 0.3, 0.2, 0.4], [0.2, 0.2, 0.3, 0.3])
    assert noisy["p_value"] > 0.5  # differences -0.1, +0.1, -0.1, +0.1 say nothing
    with pytest.raises(ValueError, match="equal-length"):
        paired_mean_difference([1.0], [1.0, 2.0])
    with pytest.raises(ValueError, match="finite"):
        paired_mean_difference([float("nan")], [1.0])


def pairs(both, a_only, b_only, neither):
    a = [1] * both + [1] * a_only + [0] * b_only + [0] * neither
    b = [1] * both + [0] * a_only + [1] * b_only + [0] * neither
    return a, b


def test_paired_rate_difference_is_the_rate_gap_with_an_interval_around_it():
    r = paired_rate_difference(*pairs(40, 20, 5, 35))
    assert r["n"] == 100 and r["diff"] == pytest.approx(0.15)
    lo, hi = r["ci95"]
    assert 0.0 < lo < 0.15 < hi < 0.3  # 20 vs 5 discordant: clearly positive
    # Large n: close to the Wald interval for paired proportions, sqrt(f + g - (f - g)^2 / n) / n.
    big = paired_rate_difference(*pairs(400, 200, 50, 350))
    half = 1.959964 * np.sqrt(250 - 150**2 / 1000) / 1000
    assert big["ci95"] == pytest.approx([0.15 - half, 0.15 + half], abs=0.005)
    # Same discordant counts either way: a mirrored interval.
    assert paired_rate_difference(*pairs(40, 5, 20, 35))["ci95"] == pytest.approx([-hi, -lo])
    # No discordant pair: zero difference, and an interval that still admits small differences.
    none = paired_rate_difference(*pairs(30, 0, 0, 20))
    assert none["diff"] == 0.0 and none["ci95"][0] < 0 < none["ci95"][1]
    # At the boundary the interval stays inside [-1, 1].
    top = paired_rate_difference(*pairs(0, 10, 0, 0))
    assert top["diff"] == 1.0 and 0.5 < top["ci95"][0] < 1.0 and top["ci95"][1] == 1.0
    with pytest.raises(ValueError, match="equal length"):
        paired_rate_difference([1], [1, 0])
    with pytest.raises(ValueError, match="no pairs"):
        paired_rate_difference([], [])


def test_paired_rate_difference_covers_the_true_difference_about_95_percent_of_the_time():
    # Pairs drawn from a known joint law: both 0.30, a only 0.15, b only 0.05, neither 0.50 (true diff 0.10).
    rng = np.random.default_rng(0)
    cells = rng.choice(4, p=[0.30, 0.15, 0.05, 0.50], size=(2000, 60))
    hits = 0
    for row in cells:
        counts = np.bincount(row, minlength=4)
        lo, hi = paired_rate_difference(*pairs(*counts.tolist()))["ci95"]
        hits += lo <= 0.10 <= hi
    assert 0.93 <= hits / len(cells) <= 0.975


def test_mcnemar_power_equals_enumerating_every_outcome():
    import itertools

    from gazereg.evaluation.stats import binom_two_sided, mcnemar_power

    pa, pb, n = 0.3, 0.05, 7
    probs = {"a": pa, "b": pb, "c": 1 - pa - pb}
    want = 0.0
    for outcome in itertools.product("abc", repeat=n):
        k, d = outcome.count("a"), outcome.count("a") + outcome.count("b")
        if binom_two_sided(k, d) < 0.05:
            want += math.prod(probs[o] for o in outcome)
    assert mcnemar_power(pa, pb, n) == pytest.approx(want, abs=1e-12)
    assert want > 0


def test_pairs_for_power_is_the_smallest_size_reaching_it():
    from gazereg.evaluation.stats import mcnemar_power, pairs_for_power

    n = pairs_for_power(85 / 300, 8 / 300, power=0.8)
    assert mcnemar_power(85 / 300, 8 / 300, n) >= 0.8 > mcnemar_power(85 / 300, 8 / 300, n - 1)
    assert mcnemar_power(0.1, 0.1, 200) < 0.1  # no effect: power stays near alpha
    with pytest.raises(ValueError):
        mcnemar_power(0.0, 0.0, 10)
