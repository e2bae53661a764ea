import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from gazereg.heatmaps import check_heatmaps, heatmaps_from_points

unit = st.floats(0, 1, allow_nan=False)


@given(u=unit, v=unit, sigma=st.floats(0.5, 8), h=st.integers(4, 40), w=st.integers(4, 40))
def test_heatmap_sums_to_one_and_peaks_at_point(u, v, sigma, h, w):
    maps, valid = heatmaps_from_points(torch.tensor([[u, v]]), (h, w), sigma)
    assert valid.all()
    assert (maps >= 0).all()
    assert maps.sum().item() == pytest.approx(1.0, abs=1e-5)
    i, j = divmod(int(maps[0].argmax()), w)
    assert abs(i - (v * h - 0.5)) <= 1.0 and abs(j - (u * w - 0.5)) <= 1.0


def test_missing_and_out_of_frame_points_are_invalid_not_wrong_maps():
    pts = np.array([[0.5, 0.5], [np.nan, 0.5], [1.2, 0.3], [-0.1, 0.3], [0.5, 0.5]])
    maps, valid = heatmaps_from_points(pts, (16, 16), 2.0, valid=np.array([1, 1, 1, 1, 0], bool))
    assert valid.tolist() == [True, False, False, False, False]
    assert (maps[~valid] == 0).all()
    assert torch.isfinite(maps).all()


def test_truncated_kernel_matches_glc_19x19():
    maps, _ = heatmaps_from_points(torch.tensor([[0.5, 0.5]]), (64, 64), 3.2, truncate=9)
    nz = torch.nonzero(maps[0])
    assert (nz.max(0).values - nz.min(0).values + 1).tolist() == [19, 19]


def test_batched_shapes():
    pts = torch.rand(3, 5, 2)
    maps, valid = heatmaps_from_points(pts, (8, 12), 1.5)
    assert maps.shape == (3, 5, 8, 12) and valid.shape == (3, 5)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -1.0])
def test_check_heatmaps_rejects_nan_inf_negative(bad):
    h = torch.full((2, 4, 4), 1 / 16)
    h[1, 2, 2] = bad
    with pytest.raises(ValueError, match="NaN|negative"):
        check_heatmaps(h)


def test_bad_arguments():
    with pytest.raises(ValueError, match="sigma"):
        heatmaps_from_points(torch.rand(2, 2), (8, 8), 0.0)
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\)"):
        heatmaps_from_points(torch.rand(2, 3), (8, 8), 1.0)
