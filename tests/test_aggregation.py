import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from gazereg.aggregation import AggregationConfig, aggregate
from gazereg.heatmaps import heatmaps_from_points

configs = st.builds(
    AggregationConfig,
    past=st.integers(0, 4),
    future=st.integers(0, 4),
    kernel=st.sampled_from(["uniform", "gaussian", "exponential"]),
    sigma=st.floats(0.5, 4),
    tau=st.floats(0.5, 4),
)


def _episode(T=10, g=None):
    pts = torch.rand(T, 2, generator=g) * 0.8 + 0.1
    return heatmaps_from_points(pts, (12, 12), 1.5)


@given(cfg=configs, T=st.integers(1, 12))
def test_aggregated_maps_are_distributions(cfg, T):
    maps, valid = _episode(T, torch.Generator().manual_seed(T))
    out, ok = aggregate(maps, valid, cfg)
    assert out.shape == maps.shape and ok.all()
    assert (out >= 0).all()
    torch.testing.assert_close(out.sum((-1, -2)), torch.ones(T), atol=1e-5, rtol=0)


@given(cfg=configs, T=st.integers(1, 8))
def test_identical_frames_are_a_fixed_point(cfg, T):
    one, _ = heatmaps_from_points(torch.tensor([[0.3, 0.7]]), (10, 10), 1.0)
    maps = one.expand(T, -1, -1).clone()
    out, _ = aggregate(maps, None, cfg)
    torch.testing.assert_close(out, maps, atol=1e-6, rtol=0)


def test_causal_window_only_uses_the_past():
    maps, valid = _episode(6, torch.Generator().manual_seed(1))
    out, _ = aggregate(maps, valid, AggregationConfig(past=2, future=0))
    torch.testing.assert_close(out[3], (maps[1] + maps[2] + maps[3]) / 3, atol=1e-6, rtol=0)
    torch.testing.assert_close(out[0], maps[0], atol=1e-6, rtol=0)  # truncated at the episode start
    fut, _ = aggregate(maps, valid, AggregationConfig(past=0, future=1))
    torch.testing.assert_close(fut[5], maps[5], atol=1e-6, rtol=0)  # truncated at the end
    torch.testing.assert_close(fut[2], (maps[2] + maps[3]) / 2, atol=1e-6, rtol=0)


def test_invalid_frames_are_skipped_and_isolated_ones_stay_invalid():
    maps, valid = _episode(7, torch.Generator().manual_seed(2))
    valid = valid.clone()
    valid[2] = False
    maps[2] = 0
    out, ok = aggregate(maps, valid, AggregationConfig(past=1, future=1))
    assert ok[2]  # neighbours fill it
    torch.testing.assert_close(out[2], (maps[1] + maps[3]) / 2, atol=1e-6, rtol=0)
    none_valid = torch.zeros(5, dtype=torch.bool)
    out, ok = aggregate(torch.zeros(5, 12, 12), none_valid, AggregationConfig(past=1, future=1))
    assert not ok.any() and (out == 0).all()


def test_gaussian_weights_prefer_the_centre():
    maps, valid = _episode(9, torch.Generator().manual_seed(3))
    out, _ = aggregate(maps, valid, AggregationConfig(past=4, future=4, kernel="gaussian", sigma=0.3))
    torch.testing.assert_close(out[4], maps[4], atol=1e-3, rtol=0)


def test_bad_input():
    with pytest.raises(ValueError, match="empty"):
        aggregate(torch.zeros(0, 4, 4))
    with pytest.raises(ValueError, match="NaN"):
        aggregate(torch.full((2, 4, 4), float("nan")))
    with pytest.raises(ValueError, match="--aggregation.past must be an integer >= 0, got -1"):
        AggregationConfig(past=-1)
