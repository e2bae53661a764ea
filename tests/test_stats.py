import math

import numpy as np
import pytest

from gazereg.evaluation.stats import (
    binom_two_sided,
    fisher_exact,
    holm,
    mcnemar_exact,
    paired_rate_difference,
    steps_to_threshold,
    student_t_cdf,
    student_t_quantile,
    unit_mean_difference,
    wilson,
)


def test_wilson_known_values():
    lo, hi = wilson(8, 20)
    assert lo == pytest.approx(0.2188, abs=1e-3) and hi == pytest.approx(0.6134, abs=1e-3)
    assert wilson(0, 10)[0] == 0.0 and wilson(10, 10)[1] == pytest.approx(1.0)
    assert wilson(0, 0) == (0.0, 1.0)
    with pytest.raises(ValueError):
        wilson(3, 2)


@pytest.mark.parametrize("n", [25, 50, 150, 250, 750])
def test_wilson_holds_its_rate_at_the_ends(n):
    # at these n the formula's lower bound at 0 successes (or upper at n) misses the rate by a rounding error
    assert wilson(0, n)[0] == 0.0 and wilson(n, n)[1] == 1.0
    lo, hi = wilson(0, n)
    assert 0.0 < hi < 1.0 and 0.0 < wilson(n, n)[0] < 1.0
    assert lo <= 0 / n <= hi


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


def test_student_t_matches_known_values_and_limits():
    assert student_t_cdf(0.0, 3) == 0.5
    assert student_t_cdf(1.0, 1) == pytest.approx(0.75)  # Cauchy: 1/2 + atan(1)/pi
    assert student_t_cdf(-1.0, 2) == pytest.approx(0.5 - 0.5 / math.sqrt(3))  # df 2: t / (2 sqrt(2 + t^2))
    # Two-sided 5% critical values from any t table, and the normal limit.
    for df, t in [(1, 12.7062), (2, 4.3027), (4, 2.7764), (9, 2.2622), (30, 2.0423)]:
        assert student_t_quantile(0.975, df) == pytest.approx(t, abs=1e-4)
    assert student_t_quantile(0.975, 2000) == pytest.approx(1.961151, abs=1e-5)  # near the normal 1.959964
    assert student_t_quantile(0.025, 5) == pytest.approx(-student_t_quantile(0.975, 5))
    for bad in [(0.5, 0), (0.0, 3), (1.0, 3)]:
        with pytest.raises(ValueError):
            student_t_quantile(*bad)


def test_student_t_matches_scipy():
    stats = pytest.importorskip("scipy.stats")
    for df in (1, 2, 3, 6, 11):
        for t in (-7.5, -1.1, 0.3, 2.9):
            assert student_t_cdf(t, df) == pytest.approx(float(stats.t.cdf(t, df)), abs=1e-12)


def test_unit_mean_difference_uses_seeds_as_the_unit():
    r = unit_mean_difference([0.1, 0.3, 0.2])
    assert r["mean_diff"] == pytest.approx(0.2) and r["above"] == 3 and r["below"] == 0
    half = 4.302653 * 0.1 / math.sqrt(3)  # t(0.975, 2) * sd / sqrt(n)
    assert r["ci95"] == pytest.approx([0.2 - half, 0.2 + half], abs=1e-6)
    assert r["sign_flip_p"] == pytest.approx(0.25) and r["p_floor"] == pytest.approx(0.25)
    # Seeds that disagree: the interval spans 0 and the sign-flip test sees it.
    r = unit_mean_difference([-0.03, 0.25, 0.0])
    assert r["ci95"][0] < 0 < r["ci95"][1] and (r["above"], r["below"]) == (1, 1)
    assert r["sign_flip_p"] == pytest.approx(1.0)  # every sign pattern's |mean| is 0.22/3 or 0.28/3
    assert unit_mean_difference([0.1] * 5)["p_floor"] == pytest.approx(2 / 32)
    for bad in ([0.1], [0.1, float("nan")]):
        with pytest.raises(ValueError):
            unit_mean_difference(bad)


def test_holm_steps_down_and_keeps_the_input_order():
    # sorted 0.01, 0.02, 0.04 times 3, 2, 1 -> 0.03, 0.04, 0.04 (made non-decreasing)
    assert holm([0.04, 0.01, 0.02]) == pytest.approx([0.04, 0.03, 0.04])
    assert holm([0.5, 0.6]) == pytest.approx([1.0, 1.0])  # capped at 1
    assert holm([0.03]) == [0.03] and holm([]) == []
    # a family-wise rate: never below the raw p, never above Bonferroni's
    ps = [0.001, 0.2, 0.013, 0.04, 0.5]
    for raw, adj in zip(ps, holm(ps), strict=True):
        assert raw <= adj <= min(1.0, len(ps) * raw)
