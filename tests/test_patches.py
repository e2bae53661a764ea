import pytest
import torch
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from gazereg.heatmaps import heatmaps_from_points
from gazereg.patches import PatchGeometry, grid_to_image, patch_distribution, patch_distributions


@st.composite
def geometries(draw):
    patch = draw(st.sampled_from([4, 8, 14, 16]))
    shuffle = draw(st.sampled_from([1, 1, 2]))
    gh, gw = draw(st.integers(1, 6)), draw(st.integers(1, 6))
    src = (draw(st.integers(16, 120)), draw(st.integers(16, 120)))
    crop = draw(
        st.one_of(
            st.none(),
            st.tuples(st.floats(0, 0.3), st.floats(0, 0.3), st.floats(0.6, 1), st.floats(0.6, 1)),
        )
    )
    return PatchGeometry(
        input_hw=(gh * patch * shuffle, gw * patch * shuffle),
        patch_size=patch,
        src_hw=src,
        resize=draw(st.sampled_from(["stretch", "fit", "cover"])),
        pad=draw(st.sampled_from(["topleft", "centre", "bottomright"])),
        orientation=draw(st.sampled_from(["none", "rot180", "hflip", "vflip"])),
        crop_box=crop,
        pixel_shuffle=shuffle,
    )


@given(geom=geometries(), seed=st.integers(0, 10_000))
def test_patch_distribution_is_a_distribution(geom, seed):
    heat = torch.rand(3, 20, 24, generator=torch.Generator().manual_seed(seed))
    heat = heat / heat.sum((-1, -2), keepdim=True)
    dist, valid = patch_distribution(heat, geom)
    assert dist.shape == (3, geom.n_patches)
    assert (dist >= 0).all()
    torch.testing.assert_close(dist.sum(-1), torch.ones(3), atol=1e-5, rtol=0)


@given(geom=geometries())
def test_pooling_conserves_mass_when_nothing_is_cropped(geom):
    assume(geom.resize != "cover" and geom.crop_box is None)
    heat = torch.rand(16, 16, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    my, mx = geom.overlap(16, 0), geom.overlap(16, 1)
    pooled = my @ heat @ mx.T
    assert pooled.sum().item() == pytest.approx(heat.sum().item(), rel=1e-9)


@settings(suppress_health_check=[HealthCheck.filter_too_much])  # points off the image or on patch borders
@given(geom=geometries(), u=st.floats(0.02, 0.98), v=st.floats(0.02, 0.98))
def test_gaze_point_lands_in_the_patch_holding_that_pixel(geom, u, v):
    """Round trip: a sharp heatmap at (u, v) puts its largest patch mass at geometry.patch_index((u, v))."""
    idx = int(geom.patch_index(torch.tensor([u, v])))
    assume(idx >= 0)
    p = geom.map_points(torch.tensor([u, v]))
    gh, gw = geom.grid_hw
    # stay away from patch borders, where a tiny Gaussian straddles two patches
    fu, fv = (p[0] * gw) % 1, (p[1] * gh) % 1
    assume(0.12 < fu < 0.88 and 0.12 < fv < 0.88)
    # a single hot cell of a fine grid: its extent (< 1 px after any resize here) stays inside the patch
    heat, ok = heatmaps_from_points(torch.tensor([[u, v]]), (2000, 2000), 0.3, truncate=0)
    dist, valid = patch_distribution(heat, geom, ok)
    assert valid.all()
    assert int(dist[0].argmax()) == idx


def test_known_geometry_letterbox_topleft():
    # transformers PI0-style: a 100x200 frame fitted into 64x64, image at the top-left (padding bottom/right).
    geom = PatchGeometry(input_hw=(64, 64), patch_size=16, src_hw=(100, 200), resize="fit", pad="topleft")
    uv = geom.map_points(torch.tensor([[0.0, 0.0], [1.0, 1.0]]))
    torch.testing.assert_close(uv, torch.tensor([[0.0, 0.0], [1.0, 0.5]]))
    heat = torch.full((10, 20), 1 / 200)
    dist, _ = patch_distribution(heat, geom, eps=0)
    grid = dist.reshape(4, 4)
    assert grid[2:].sum() == 0  # padding rows get nothing
    torch.testing.assert_close(grid[:2].sum(), torch.tensor(1.0))


def test_known_geometry_letterbox_bottomright():
    # LeRobot resize_with_pad (SmolVLA): padding on the top and left, the image at the bottom.
    geom = PatchGeometry(input_hw=(64, 64), patch_size=16, src_hw=(100, 200), resize="fit", pad="bottomright")
    torch.testing.assert_close(geom.map_points(torch.tensor([[0.0, 0.0]])), torch.tensor([[0.0, 0.5]]))
    dist, _ = patch_distribution(torch.full((10, 20), 1 / 200), geom, eps=0)
    assert dist.reshape(4, 4)[:2].sum() == 0


def test_rot180_maps_top_left_to_bottom_right():
    geom = PatchGeometry(input_hw=(32, 32), patch_size=16, orientation="rot180")
    assert int(geom.patch_index(torch.tensor([0.1, 0.1]))) == 3


def test_cover_crops_mass_away_and_renormalises():
    geom = PatchGeometry(input_hw=(32, 32), patch_size=16, src_hw=(32, 64), resize="cover")
    heat = torch.zeros(8, 16)
    heat[4, 1] = 1.0  # far left: cropped away by the centre crop
    dist, valid = patch_distribution(heat, geom)
    assert not valid.item()
    torch.testing.assert_close(dist, torch.full((1, 4), 0.25)[0])


def test_grid_that_does_not_fit_is_an_error_naming_both():
    with pytest.raises(ValueError, match=r"96x96.*14 px"):
        PatchGeometry(input_hw=(96, 96), patch_size=14)
    geom = PatchGeometry(input_hw=(96, 96), patch_size=12)
    with pytest.raises(ValueError, match=r"\(4, 4\).*\(8, 8\)"):
        geom.check_grid((4, 4))


def test_bad_heatmaps_and_cameras():
    geom = PatchGeometry(input_hw=(32, 32), patch_size=16)
    with pytest.raises(ValueError, match="NaN"):
        patch_distribution(torch.full((4, 4), float("nan")), geom)
    dist, valid = patch_distribution(torch.zeros(2, 4, 4), geom)
    assert not valid.any() and torch.isfinite(dist).all()
    with pytest.raises(KeyError, match="wrist"):
        patch_distributions({"wrist": torch.ones(4, 4)}, {"front": geom})


def test_grid_to_image_inverts_pooling_for_uniform_patches():
    geom = PatchGeometry(input_hw=(32, 32), patch_size=8)
    dist = torch.zeros(16)
    dist[5] = 1.0
    img = grid_to_image(dist, geom, (16, 16))
    back, _ = patch_distribution(img, geom, eps=0)
    torch.testing.assert_close(back, dist)
