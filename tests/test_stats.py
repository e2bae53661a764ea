import pytest

from gazevla.stats import binom_two_sided, fisher_exact, mcnemar_exact, steps_to_threshold, wilson


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
    from gazevla.stats import paired_mean_difference

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
