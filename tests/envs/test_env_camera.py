"""Camera geometry: the projection formula, orientation, and agreement with what MuJoCo renders."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gazereg.envs.camera import CameraGeometry, needs_rot180


def _look_down_x() -> tuple[np.ndarray, np.ndarray]:
    """A camera at the origin looking along world +x, image-up = world +z (columns: cam x, y, z in world)."""
    cam_x = np.array([0.0, -1.0, 0.0])  # image right = world -y
    cam_y = np.array([0.0, 0.0, 1.0])  # image up = world +z
    cam_z = np.cross(cam_x, cam_y)  # looks along -cam_z = +x
    return np.zeros(3), np.stack([cam_x, cam_y, cam_z], axis=1)


def test_projection_formula():
    pos, R = _look_down_x()
    geo = CameraGeometry("c", height=100, width=200, fovy_deg=90.0, rot180=False)
    assert geo.focal_px == pytest.approx(50.0)
    uv = geo.project(np.array([[2.0, 0.0, 0.0], [1.0, 0.0, 0.5], [1.0, -0.5, 0.0], [-1.0, 0.0, 0.0]]), pos, R)
    np.testing.assert_allclose(uv[0], [0.5, 0.5])  # straight ahead: the centre
    np.testing.assert_allclose(uv[1], [0.5, 0.25])  # up by tan = 0.5: 25 px above the centre of 100
    np.testing.assert_allclose(uv[2], [0.625, 0.5])  # right by 0.5: 25 px of 200 to the right
    assert np.isnan(uv[3]).all()  # behind the camera


def test_rot180_flips_both_axes_and_images():
    pos, R = _look_down_x()
    a = CameraGeometry("c", 64, 64, 60.0, rot180=False)
    b = CameraGeometry("c", 64, 64, 60.0, rot180=True)
    p = np.array([1.0, -0.2, 0.1])
    np.testing.assert_allclose(b.project(p, pos, R), 1 - a.project(p, pos, R))
    img = np.arange(2 * 3 * 3).reshape(2, 3, 3).astype(np.uint8)
    np.testing.assert_array_equal(b.orient(img), img[::-1, ::-1])
    np.testing.assert_array_equal(a.orient(img), img)
    # pixel lookup follows the same convention: pixel j covers [j, j + 1) / W
    np.testing.assert_array_equal(a.uv_to_pixel(np.array([0.0, 0.999])), [63, 0])


def test_upside_down_cameras_are_detected():
    _, R = _look_down_x()
    assert not needs_rot180(R)
    assert needs_rot180(R @ np.diag([-1.0, -1.0, 1.0]))  # rolled by 180 degrees: image-up points down
    top = np.eye(3)  # looking straight down, image-up horizontal: left as is
    assert not needs_rot180(top)


@pytest.fixture(scope="module")
def reach_env(gl_backend):
    from gazereg.envs import MetaWorldEnv

    env = MetaWorldEnv(
        "reach-v3", cameras=("corner2", "corner", "topview"), image_size=96, gl_backend=gl_backend
    )
    yield env
    env.close()


def _green(img: np.ndarray) -> np.ndarray:
    i = img.astype(int)
    return (i[..., 1] > 150) & (i[..., 0] < 90) & (i[..., 2] < 90)


@pytest.mark.sim
@pytest.mark.parametrize("camera", ["corner2", "corner", "topview"])
def test_goal_sphere_renders_where_it_projects(reach_env, camera):
    """The green goal sphere's pixels are centred on the projected goal (within 1 px) in the upright image."""
    for seed in (0, 11):
        obs, info = reach_env.reset(seed=seed)
        img = obs["images"][camera]
        uv = reach_env.project(info["goal_pos"], camera)
        g = _green(img)
        assert g.sum() >= 3, f"goal sphere not visible in {camera} (seed {seed})"
        ys, xs = np.nonzero(g)
        centroid = np.array([(xs + 0.5).mean() / 96, (ys + 0.5).mean() / 96])
        assert np.abs(centroid - uv).max() * 96 < 1.0
        row, col = reach_env.camera_geometry(camera).uv_to_pixel(uv)
        assert g[max(row - 1, 0) : row + 2, max(col - 1, 0) : col + 2].any()


@pytest.mark.sim
def test_images_are_upright(reach_env):
    """Up in the world is up in every image: a point above the goal projects higher (smaller v); and the
    corner cameras, which MuJoCo renders upside down, are the ones rotated."""
    _, info = reach_env.reset(seed=0)
    goal = info["goal_pos"]
    for cam in ("corner2", "corner"):
        low, high = reach_env.project(np.stack([goal, goal + [0, 0, 0.2]]), cam)
        assert high[1] < low[1] - 0.02
        assert reach_env.camera_geometry(cam).rot180
    assert not reach_env.camera_geometry("topview").rot180
    # In corner2 the floor and table fill the bottom rows; the top rows are the plain background.
    img = reach_env.reset(seed=0)[0]["images"]["corner2"].astype(float)
    top, bottom = img[:10], img[-10:]
    assert top.std(axis=(0, 1)).mean() < bottom.std(axis=(0, 1)).mean()


@pytest.mark.sim
def test_fov_and_focal_length_come_from_the_model(reach_env):
    geo = reach_env.camera_geometry("corner2")
    assert geo.fovy_deg == pytest.approx(60.0)
    assert geo.focal_px == pytest.approx(0.5 * 96 / math.tan(math.radians(30)))
    with pytest.raises(KeyError, match="not rendered"):
        reach_env.camera_geometry("gripperPOV")
