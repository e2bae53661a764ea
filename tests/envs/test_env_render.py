"""Backend selection (no OpenGL needed), mesh simplification, and the render-only model copy."""

from __future__ import annotations

import numpy as np
import pytest

from gazereg.envs import render
from gazereg.envs.render import RenderBackendError, decimate_mesh, default_mesh_cell, select_gl_backend


def test_user_choice_is_respected(monkeypatch):
    monkeypatch.setattr(render, "egl_status", lambda: (True, []))
    assert select_gl_backend({"MUJOCO_GL": "osmesa"}) == "osmesa"
    assert select_gl_backend({"MUJOCO_GL": " EGL "}) == "egl"
    with pytest.raises(RenderBackendError, match="not a backend"):
        select_gl_backend({"MUJOCO_GL": "vulkan"})


def test_egl_first_then_osmesa_with_a_message(monkeypatch):
    monkeypatch.setattr(render, "egl_status", lambda: (True, []))
    monkeypatch.setattr(render, "osmesa_status", lambda: (True, []))
    assert select_gl_backend({}) == "egl"
    monkeypatch.setattr(render, "egl_status", lambda: (False, ["libEGL (package libegl1)"]))
    with pytest.warns(RuntimeWarning, match="libegl1 libegl-mesa0 libgl1-mesa-dri"):
        assert select_gl_backend({}) == "osmesa"


def test_no_backend_names_the_packages(monkeypatch):
    monkeypatch.setattr(render, "egl_status", lambda: (False, ["libEGL (package libegl1)"]))
    monkeypatch.setattr(render, "osmesa_status", lambda: (False, ["libOSMesa (package libosmesa6)"]))
    with pytest.raises(RenderBackendError, match="libosmesa6") as e:
        select_gl_backend({})
    assert "libegl1 libegl-mesa0 libgl1-mesa-dri" in str(e.value)


def test_this_machine_has_a_headless_backend():
    # The project's machines render with EGL (Mesa llvmpipe); this is what every sim test uses.
    assert select_gl_backend({}) in ("egl", "osmesa")


def test_decimate_mesh_merges_close_vertices_and_drops_degenerate_faces():
    # A fine grid of a unit square (2 triangles per cell) becomes a coarse one.
    n = 21
    xs, ys = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    vert = np.stack([xs.ravel(), ys.ravel(), np.zeros(n * n)], 1)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1
            faces += [(a, b, d), (a, d, c)]
    face = np.array(faces)
    v2, f2 = decimate_mesh(vert, face, cell=0.26)
    assert len(v2) < len(vert) / 10 and 0 < len(f2) < len(face) / 10
    assert f2.min() >= 0 and f2.max() < len(v2)
    assert (f2[:, 0] != f2[:, 1]).all() and (f2[:, 1] != f2[:, 2]).all() and (f2[:, 0] != f2[:, 2]).all()
    assert v2.min() >= 0 and v2.max() <= 1  # merged vertices are averages: inside the original hull


def test_default_mesh_cell_stays_below_a_pixel():
    assert default_mesh_cell(64, 64) == 0.01
    assert default_mesh_cell(128, 128) == 0.01
    assert default_mesh_cell(224, 224) == 0.005
    assert default_mesh_cell(480, 640) is None


@pytest.mark.sim
def test_simplified_render_matches_the_full_model(gl_backend):
    """The render-only copy with simplified meshes draws the same picture as the original meshes."""
    from gazereg.envs import MetaWorldEnv

    imgs = {}
    for cell in (0.01, None):
        env = MetaWorldEnv(
            "pick-place-v3", cameras=("corner2",), image_size=96, mesh_cell=cell, gl_backend=gl_backend
        )
        obs, _ = env.reset(seed=3)
        imgs[cell] = obs["images"]["corner2"].astype(np.int16)
        env.close()
    diff = np.abs(imgs[0.01] - imgs[None])
    assert diff.mean() < 1.5  # grey levels
    assert (diff.max(-1) > 40).mean() < 0.01
