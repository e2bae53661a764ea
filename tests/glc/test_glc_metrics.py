"""GLC metrics on hand-checkable maps, and the baselines."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gazereg.gaze.glc.metrics import (
    THRESHOLDS,
    auc_scores,
    center_prior_maps,
    evaluate_gaze,
    f1_recall_precision,
    fit_center_prior,
    gaussian_blur,
    minmax_normalize,
    uniform_maps,
)
from gazereg.gaze.glc.targets import gaze_target_maps


def _gt_block() -> np.ndarray:
    gt = np.zeros((8, 8))
    gt[2:4, 2:4] = 0.25  # 4 ground-truth pixels
    return gt


def test_thresholds():
    assert np.allclose(THRESHOLDS, [0, 0.002, 0.004, 0.006, 0.008, 0.01, 0.012, 0.014, 0.016, 0.018, 0.02])


def test_minmax_per_frame():
    x = np.stack([np.arange(4.0).reshape(2, 2), 10 + 2 * np.arange(4.0).reshape(2, 2)])
    out = minmax_normalize(x)
    assert np.allclose(out[0], out[1], atol=1e-6)
    assert np.allclose(out[0].ravel(), np.array([0, 1, 2, 3]) / 3, atol=1e-6)


def test_half_precision_full_recall():
    pred = np.zeros((8, 8))
    pred[2:4, 2:6] = 1.0  # 8 predicted pixels, 4 of them correct
    s = f1_recall_precision(pred[None], _gt_block()[None])
    assert s.recall == pytest.approx(1.0, abs=1e-5)
    assert s.precision == pytest.approx(0.5, abs=1e-5)
    assert s.f1 == pytest.approx(2 / 3, abs=1e-5)
    assert s.threshold == 0.0 and s.n_frames == 1


def test_averaging_over_frames_and_fixation_mask():
    hit = np.zeros((8, 8))
    hit[2:4, 2:6] = 1.0
    miss = np.zeros((8, 8))
    miss[6:8, 6:8] = 1.0
    pred = np.stack([hit, miss])
    gt = np.stack([_gt_block(), _gt_block()])
    s = f1_recall_precision(pred, gt)
    assert s.recall == pytest.approx(0.5, abs=1e-5)  # (1 + 0) / 2
    assert s.precision == pytest.approx(0.25, abs=1e-5)  # (0.5 + 0) / 2
    assert s.f1 == pytest.approx(2 * 0.5 * 0.25 / 0.75, abs=1e-5)  # from the mean P and R
    s = f1_recall_precision(pred, gt, frame_mask=[True, False])
    assert s.f1 == pytest.approx(2 / 3, abs=1e-5) and s.n_frames == 1


def test_best_threshold_is_selected():
    pred = np.zeros((8, 8))
    pred[0, :] = 0.01  # 8 weak false positives
    pred[2:4, 2:4] = 1.0
    s = f1_recall_precision(pred[None], _gt_block()[None])
    # thresholds below 0.01 keep the weak pixels (P = 4/12); from 0.01 on only the block survives
    assert s.f1_curve[0] == pytest.approx(2 * (1 / 3) / (4 / 3), abs=1e-5)
    assert s.threshold == pytest.approx(0.01)
    assert s.precision == pytest.approx(1.0, abs=1e-5) and s.f1 == pytest.approx(1.0, abs=1e-5)


def test_auc_peak_on_gaze_is_one_far_is_low():
    h = w = 64
    pred = np.zeros((h, w))
    pred[32, 16] = 1.0
    gaze = np.array([[16 / 63, 32 / 63]])  # (u, v) -> pixel (row 32, col 16)
    assert auc_scores(pred[None], gaze) == pytest.approx(1.0)
    near = np.zeros((h, w))
    near[32, 19] = 1.0  # 3 px off
    auc_near = auc_scores(near[None], gaze)
    assert 0.97 < auc_near < 1.0
    # the blur is truncated at radius int(4 * 3.2 + 0.5) = 13, so a far miss only loses the blurred
    # area: in a corner, 14 x 14 pixels score above the (zero) value at the gaze point
    far = np.zeros((h, w))
    far[0, 63] = 1.0
    assert auc_scores(far[None], np.array([[0.0, 1.0]])) == pytest.approx(1 - 14 * 14 / 4096)


def test_auc_uniform_prediction_falls_back_to_centre():
    maps = uniform_maps((1, 16, 16)).numpy()
    assert auc_scores(maps, np.array([[8 / 15, 8 / 15]])) == pytest.approx(1.0)


def test_gaussian_blur_matches_scipy():
    ndimage = pytest.importorskip("scipy.ndimage")
    rng = np.random.default_rng(0)
    img = rng.random((20, 17))
    for sigma in (0.8, 3.2):
        assert np.allclose(gaussian_blur(img, sigma), ndimage.gaussian_filter(img, sigma), atol=1e-10)


def test_baselines_give_a_floor():
    n, t, s = 6, 4, 32
    gaze = torch.full((n, t, 2), 0.5) + 0.03 * torch.randn(
        n, t, 2, generator=torch.Generator().manual_seed(0)
    )
    center, sigma = fit_center_prior(gaze)
    assert abs(center[0] - 0.5) < 0.05 and sigma[0] < 0.1
    prior = center_prior_maps((n, t, s, s), center, sigma)
    torch.testing.assert_close(prior.sum((-2, -1)), torch.ones(n, t))
    s_prior = evaluate_gaze(prior, gaze)
    s_uniform = evaluate_gaze(uniform_maps((n, t, s, s)), gaze)
    assert s_uniform.f1 == 0.0
    assert s_prior.f1 > 0.3 and s_prior.auc > 0.9
    assert s_prior.n_frames == n * t


def test_perfect_prediction_scores_high():
    g = torch.Generator().manual_seed(1)
    gaze = 0.2 + 0.6 * torch.rand(3, 4, 2, generator=g)
    valid = torch.ones(3, 4, dtype=torch.bool)
    maps = gaze_target_maps(gaze, valid, (64, 64))
    s = evaluate_gaze(maps[:, None], gaze, valid)
    # the binarised target (> 0.001) is narrower than the prediction above 2% of its peak, so even a
    # perfect map keeps precision below 1 under this protocol
    assert s.recall > 0.999 and 0.6 < s.precision < 0.8 and s.f1 > 0.8 and s.auc > 0.995
