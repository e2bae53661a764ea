import pytest
import torch

from gazereg.metrics import alignment_metrics, auc_judd, cc, kl, mass_in_region, nss, sim


def test_identical_maps_are_perfectly_aligned():
    g = torch.softmax(torch.randn(3, 25, generator=torch.Generator().manual_seed(0)), -1)
    assert torch.allclose(kl(g, g), torch.zeros(3), atol=1e-6)
    assert torch.allclose(cc(g, g), torch.ones(3))
    assert torch.allclose(sim(g, g), torch.ones(3))


def test_known_values():
    fix = torch.tensor([0, 0, 1.0, 0])
    good = torch.tensor([0.1, 0.1, 0.7, 0.1])
    bad = torch.tensor([0.7, 0.1, 0.1, 0.1])
    assert auc_judd(fix, good).item() == pytest.approx(1.0)
    assert auc_judd(fix, bad).item() == pytest.approx(0.5)  # the fixation ties the lowest values: chance
    assert auc_judd(fix, torch.tensor([0.5, 0.1, 0.3, 0.1])).item() == pytest.approx(1 / 6 + 2 / 3)
    assert nss(fix, good).item() == pytest.approx(1.5)  # (0.7 - 0.25) / std
    assert cc(good, bad).item() < 0
    assert mass_in_region(good, fix > 0).item() == pytest.approx(0.7)
    assert sim(good, bad).item() == pytest.approx(0.4)


def test_auc_is_nan_when_undefined_and_summary_skips_it():
    assert torch.isnan(auc_judd(torch.zeros(4), torch.rand(4)))
    g = torch.softmax(torch.randn(4, 16), -1)
    m = alignment_metrics(g, g, torch.tensor([True, True, False, True]))
    assert set(m) == {"kl", "cc", "sim", "nss", "auc_judd"}
    assert alignment_metrics(g, g, torch.zeros(4, dtype=torch.bool)) == {}
