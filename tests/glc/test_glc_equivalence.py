"""Numerical equivalence with the official GLC_Gaze (README: synthetic weights + fixed input clip)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from glc_testutils import synthetic_state_dict

from gazereg.gaze.glc import GLC, GLCConfig


def test_matches_official_output(synthetic_io):
    model = GLC(GLCConfig.full()).eval()
    model.load_state_dict(synthetic_state_dict(model), strict=True)
    x = torch.from_numpy(synthetic_io["input_lowres"])
    x = F.interpolate(x, size=(8, 256, 256), mode="trilinear", align_corners=False)
    x = (x - 0.45) / 0.225
    with torch.no_grad():
        out = model(x)
    ref = torch.from_numpy(synthetic_io["output_logits"])
    assert out.shape == ref.shape == (1, 1, 8, 64, 64)
    err = (out - ref).abs().max().item()
    assert err < 1e-3, f"max abs difference {err:.2e}"
