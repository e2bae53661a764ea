"""The report's figures: stack_figures, the pooled report's attention figure from its folders'."""

import numpy as np
from matplotlib.image import imread, imsave

from gazereg.report.figures import stack_figures


def test_stack_pads_the_narrower_white_and_keeps_each_figure(tmp_path):
    wide = np.zeros((4, 6, 3))
    narrow = np.full((2, 3, 3), 0.5)
    imsave(tmp_path / "a.png", wide)
    imsave(tmp_path / "b.png", narrow)
    out = imread(stack_figures([tmp_path / "a.png", tmp_path / "b.png"], tmp_path / "f" / "s.png"))
    assert out.shape[:2] == (6, 6)
    assert np.allclose(out[:4, :, :3], 0.0)
    assert np.allclose(out[4:, :3, :3], 0.5, atol=0.01)
    assert np.allclose(out[4:, 3:, :3], 1.0)  # padding is white, not black


def test_the_success_figure_takes_a_wilson_bound_a_rounding_error_past_its_rate(tmp_path):
    """0 of 350 successes: the Wilson lower bound may come out a hair above 0 (it once stopped a report)."""
    from gazereg.report.figures import plot_success

    cell = {"rate": 0.0, "ci95": [1e-17, 0.011]}
    full = {"rate": 1.0, "ci95": [0.98, 1.0 - 1e-16]}
    path = plot_success({"baseline": {"clean": cell, "dim:0.7": full}}, tmp_path / "s.png")
    assert path.stat().st_size > 1000
