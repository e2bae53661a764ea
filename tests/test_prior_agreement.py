"""scripts/prior_agreement.py: how far a gaze prior is from a reference on the policy's patch grid."""

import math

import numpy as np
import pytest
import torch

from gazereg.data.store import Episode, EpisodeStore


@pytest.fixture(scope="module")
def agreement(load_script):
    """scripts/prior_agreement.py loaded as a module."""
    return load_script("scripts/prior_agreement.py")


def test_peak_distance_is_chebyshev_on_the_grid_and_undefined_for_a_flat_map(agreement):
    a, b = torch.zeros(3, 16), torch.zeros(3, 16)
    a[0, 0], b[0, 0] = 1, 1  # same patch
    a[1, 0], b[1, 4 * 2 + 1] = 1, 1  # (0, 0) vs (2, 1): 2 patches apart
    a[2], b[2, 5] = 1 / 16, 1  # flat
    d = agreement.peak_distance(a, b, (4, 4))
    assert d[:2].tolist() == [0.0, 2.0] and math.isnan(d[2])


def _store_with_priors(root, priors):
    """A store of one 4-frame episode with {name: (4, 16, 16) heatmaps} as priors."""
    store = EpisodeStore(root, create=True)
    zeros = np.zeros((4, 2), np.float32)
    store.write(Episode("reach-v3", "reach", {"front": np.zeros((4, 8, 8, 3), np.uint8)}, zeros, zeros))
    for name, heat in priors.items():
        store.write_prior(name, 0, heat / heat.sum((1, 2), keepdims=True), np.ones(4, bool))
    return store


def test_agreement_is_perfect_for_the_same_prior_and_counts_patches_for_a_moved_one(agreement, tmp_path):
    from gazereg.patches import PatchGeometry

    real = np.full((4, 16, 16), 1e-3, np.float32)
    real[:, 2, 2] = 1.0  # patch (0, 0) of a 4x4 grid of 4-cell patches
    moved = np.full((4, 16, 16), 1e-3, np.float32)
    moved[:, 2, 14] = 1.0  # patch (0, 3)
    store = _store_with_priors(tmp_path / "s", {"real": real, "moved": moved, "flat": np.ones((4, 16, 16))})
    geometry = PatchGeometry(input_hw=(16, 16), patch_size=4)
    same = agreement.agreement(store, "real", "real", geometry)
    assert same["kl"] < 1e-6 and same["cc"] > 0.999 and same["peak"] == 0 and same["same_peak"] == 1.0
    far = agreement.agreement(store, "real", "moved", geometry)
    assert far["peak"] == 3 and far["same_peak"] == 0 and far["kl"] > 1 and far["frames"] == 4
    flat = agreement.agreement(store, "real", "flat", geometry)
    assert math.isnan(flat["peak"]) and "n/a (flat)" in agreement.table(
        tmp_path, "real", {"flat": flat}, geometry
    )
