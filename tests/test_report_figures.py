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
