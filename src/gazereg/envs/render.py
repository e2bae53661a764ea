"""Headless OpenGL for MuJoCo: backend selection, a fast offscreen renderer, and a render-only model copy.

Backend selection (`select_gl_backend`): a user's `MUJOCO_GL` is respected as is; otherwise EGL when its
libraries are present (Mesa llvmpipe on a CPU machine, the vendor's driver on a GPU), else OSMesa, with a
message that names the missing system packages. Nothing here sets environment variables: the chosen backend
is passed explicitly to `FastRenderer`, which imports that backend's GL context itself (MuJoCo's own
`mujoco.Renderer` fixes the backend when `mujoco` is first imported, which is why it is not used here).

Fast settings (measured on a 2-core CPU machine, Mesa llvmpipe): shadows and reflections off, an offscreen
buffer exactly the image size and no multisampling (set before the GL context is made) take a 128x128 frame
of Meta-World from about 65 ms to about 10 ms. What remains is vertex-bound (the Sawyer arm's meshes have
67k triangles), so the render-only copy of the model (`build_visual_model`) also simplifies large meshes by
vertex clustering on a grid of `mesh_cell` metres: 1 cm takes the frame to about 4 ms with a mean absolute
pixel difference of 0.3 grey levels at 128x128. Physics never sees the copy: the copy's state is synchronised
from the physics model's data before each render (`VisualMirror`), and everything that is for the eyes only
(enlarged goal markers, lighting perturbations) is applied to the copy.
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import ctypes.util
import os
import warnings
import weakref
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

HEADLESS_BACKENDS = ("egl", "osmesa")
_VALID_USER_BACKENDS = ("egl", "osmesa", "glfw", "glx", "disabled", "disable", "off", "false", "0")
EGL_PACKAGES = "libegl1 libegl-mesa0 libgl1-mesa-dri"
OSMESA_PACKAGES = "libosmesa6"


class RenderBackendError(RuntimeError):
    """No usable OpenGL backend, or a conflict between backends in one process."""


def _can_load(*names: str) -> bool:
    for name in names:
        path = ctypes.util.find_library(name)
        for candidate in [c for c in (path, f"lib{name}.so", f"lib{name}.so.1", f"lib{name}.so.0") if c]:
            try:
                ctypes.CDLL(candidate)
                return True
            except OSError:
                continue
    return False


def egl_status() -> tuple[bool, list[str]]:
    """(EGL usable, missing pieces). Needs libEGL plus a vendor library (Mesa's or NVIDIA's)."""
    missing = []
    if not _can_load("EGL"):
        missing.append("libEGL (package libegl1)")
    if not _can_load("EGL_mesa", "EGL_nvidia"):
        missing.append("an EGL vendor library (package libegl-mesa0, or the NVIDIA driver)")
    return not missing, missing


def osmesa_status() -> tuple[bool, list[str]]:
    return (True, []) if _can_load("OSMesa") else (False, [f"libOSMesa (package {OSMESA_PACKAGES})"])


def select_gl_backend(environ: Mapping[str, str] | None = None) -> str:
    """The OpenGL backend MuJoCo should render with.

    1. `MUJOCO_GL` when the user set it (validated, lower-cased).
    2. `egl` when libEGL and a vendor library load.
    3. `osmesa` (software) with a warning naming the EGL packages to install.
    Raises RenderBackendError naming the packages to install when neither is available.
    """
    environ = os.environ if environ is None else environ
    user = environ.get("MUJOCO_GL", "").strip().lower()
    if user:
        if user not in _VALID_USER_BACKENDS:
            raise RenderBackendError(
                f"MUJOCO_GL={user!r} is not a backend MuJoCo knows; use egl, osmesa or glfw"
            )
        return user
    egl_ok, egl_missing = egl_status()
    if egl_ok:
        return "egl"
    osm_ok, osm_missing = osmesa_status()
    if osm_ok:
        warnings.warn(
            f"EGL is not available ({'; '.join(egl_missing)}); rendering with OSMesa instead. "
            f"Install {EGL_PACKAGES} (apt-get install -y {EGL_PACKAGES}) for EGL.",
            RuntimeWarning,
            stacklevel=2,
        )
        return "osmesa"
    raise RenderBackendError(
        "no headless OpenGL for MuJoCo: EGL is missing "
        f"({'; '.join(egl_missing)}) and OSMesa is missing ({'; '.join(osm_missing)}). Install one of them: "
        f"`apt-get install -y {EGL_PACKAGES}` (EGL) or `apt-get install -y {OSMESA_PACKAGES}` (OSMesa), "
        "or set MUJOCO_GL to a backend that works on this machine."
    )


def gl_context_class(backend: str) -> Any:
    """Import the GLContext class of `backend` (egl, osmesa, glfw)."""
    backend = backend.lower()
    try:
        if backend == "egl":
            from mujoco.egl import GLContext
        elif backend == "osmesa":
            from mujoco.osmesa import GLContext
        elif backend in ("glfw", "glx"):
            from mujoco.glfw import GLContext
        else:
            raise RenderBackendError(
                f"rendering is disabled (gl backend {backend!r}); pass cameras=() to render nothing"
            )
    except ImportError as e:
        hint = EGL_PACKAGES if backend == "egl" else OSMESA_PACKAGES if backend == "osmesa" else "a display"
        raise RenderBackendError(
            f"cannot use the {backend!r} OpenGL backend: {e}. One process renders with one backend "
            f"(PYOPENGL_PLATFORM={os.environ.get('PYOPENGL_PLATFORM')!r}); needs {hint}."
        ) from e
    return GLContext


_LIVE_RENDERERS: weakref.WeakSet[FastRenderer] = weakref.WeakSet()
_ATEXIT_REGISTERED = False


def _close_live_renderers() -> None:
    for r in list(_LIVE_RENDERERS):
        r.close()


def _track(renderer: FastRenderer) -> None:
    """Close renderers at exit before the GL library tears its display down (EGL registers its own atexit
    on the first context; atexit runs handlers last-in first-out, so this one, registered later, runs first)."""
    global _ATEXIT_REGISTERED
    _LIVE_RENDERERS.add(renderer)
    if not _ATEXIT_REGISTERED:
        atexit.register(_close_live_renderers)
        _ATEXIT_REGISTERED = True


class FastRenderer:
    """Offscreen RGB rendering of a MuJoCo model's fixed cameras with the fast settings.

    The model's offscreen buffer is set to (height, width) and multisampling off before the GL context is
    made; shadows and reflections are off in the scene. `render` returns the image top row first, exactly
    as MuJoCo's camera sees it (no rotation; see `gazereg.envs.camera` for orientation).
    """

    def __init__(self, model: Any, height: int, width: int, backend: str, max_geom: int = 2000):
        import mujoco

        self._mj = mujoco
        self.model = model
        self.height, self.width = int(height), int(width)
        model.vis.global_.offwidth = self.width
        model.vis.global_.offheight = self.height
        model.vis.quality.offsamples = 0
        self._ctx = gl_context_class(backend)(self.width, self.height)
        self._ctx.make_current()
        self._mjr = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_50)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._mjr)
        self.scene = mujoco.MjvScene(model, maxgeom=max_geom)
        self.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        self.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        self.option = mujoco.MjvOption()
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._pert = mujoco.MjvPerturb()
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        self._buf = np.empty((self.height, self.width, 3), dtype=np.uint8)
        self.backend = backend
        _track(self)

    def render_raw(self, data: Any, camera_id: int) -> np.ndarray:
        """The frame as OpenGL reads it: bottom row first. Returns an internal buffer (copy it to keep it)."""
        mj = self._mj
        self._ctx.make_current()
        self._cam.fixedcamid = int(camera_id)
        mj.mjv_updateScene(
            self.model, data, self.option, self._pert, self._cam, mj.mjtCatBit.mjCAT_ALL, self.scene
        )
        mj.mjr_render(self._rect, self.scene, self._mjr)
        mj.mjr_readPixels(self._buf, None, self._rect, self._mjr)
        return self._buf

    def render(self, data: Any, camera_id: int) -> np.ndarray:
        """A view of the frame top row first, as the camera sees it (valid until the next render; orient or
        copy it to keep it: `CameraGeometry.orient` does both)."""
        return self.render_raw(data, camera_id)[::-1]

    def close(self) -> None:
        if getattr(self, "_ctx", None) is not None:
            try:
                self._ctx.make_current()
                self._mjr.free()
            except Exception:  # teardown must not raise (EGL may already be gone at exit)
                pass
            self._mjr = None
            with contextlib.suppress(Exception):
                self._ctx.free()
            self._ctx = None

    def __del__(self) -> None:
        self.close()


# ----- the render-only model -------------------------------------------------------------------------------
def cluster_vertices(vert: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Merge the vertices in each cube of side `cell` (metres) into their mean.

    vert (V, 3) -> merged (K, 3) float64, cluster (V,) int64: the merged vertex each input vertex became."""
    q = np.floor(np.asarray(vert) / cell).astype(np.int64)
    _, inv, counts = np.unique(q, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    merged = np.zeros((counts.size, 3))
    np.add.at(merged, inv, np.asarray(vert, dtype=np.float64))
    return merged / counts[:, None], inv


def nondegenerate(face: np.ndarray) -> np.ndarray:
    """face (F, 3) -> bool (F,): the faces whose three vertices are distinct."""
    return (face[:, 0] != face[:, 1]) & (face[:, 1] != face[:, 2]) & (face[:, 0] != face[:, 2])


def drop_unused(vert: np.ndarray, face: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keep only the vertices `face` uses: (V, 3), (F, 3) -> (V', 3), (F, 3) re-indexed."""
    used = np.unique(face)
    remap = np.full(len(vert), -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return vert[used], remap[face]


def decimate_mesh(vert: np.ndarray, face: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering: merge the vertices in each cube of side `cell`, drop degenerate and duplicate faces.

    vert (V, 3) float, face (F, 3) int -> (V', 3) float64, (F', 3) int64 with V' <= V, F' <= F.
    """
    merged, inv = cluster_vertices(vert, cell)
    f = inv[face]
    return drop_unused(merged, np.unique(f[nondegenerate(f)], axis=0))


def _quat_to_mat(quat: np.ndarray) -> np.ndarray:
    import mujoco

    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, dtype=np.float64))
    return mat.reshape(3, 3)


def set_user_mesh(
    spec_mesh: Any,
    model: Any,
    mesh_id: int,
    vert: np.ndarray,
    face: np.ndarray,
    texcoord: np.ndarray | None = None,
    facetexcoord: np.ndarray | None = None,
) -> None:
    """Replace a spec mesh's file with explicit geometry: `vert` (V, 3) in the compiled mesh's frame, `face`
    (F, 3), optional texture coordinates (T, 2) and per-face texcoord indices (F, 3). Normals are left to the
    compiler."""
    # Compiled vertices live in the mesh's inertial frame; move them back to the file's frame so that the
    # compiler re-derives the geom's placement exactly as it did for the original mesh.
    vert = vert @ _quat_to_mat(model.mesh_quat[mesh_id]).T + model.mesh_pos[mesh_id]
    spec_mesh.file = ""
    spec_mesh.scale = [1.0, 1.0, 1.0]
    spec_mesh.uservert = vert.reshape(-1).tolist()
    spec_mesh.userface = face.reshape(-1).tolist()
    spec_mesh.usernormal = []
    spec_mesh.usertexcoord = [] if texcoord is None else texcoord.reshape(-1).tolist()
    spec_mesh.userfacetexcoord = [] if facetexcoord is None else facetexcoord.reshape(-1).tolist()


def large_meshes(spec: Any, model: Any, min_faces: int) -> Iterator[tuple[Any, int, np.ndarray, np.ndarray]]:
    """The meshes of `spec` that compiled into `model` with >= `min_faces` faces: (spec mesh, mesh id,
    compiled vertices (V, 3), faces (F, 3))."""
    import mujoco

    for sm in spec.meshes:
        mid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_MESH, sm.name)
        if mid < 0 or model.mesh_facenum[mid] < min_faces:
            continue
        va, vn = model.mesh_vertadr[mid], model.mesh_vertnum[mid]
        fa, fn = model.mesh_faceadr[mid], model.mesh_facenum[mid]
        yield sm, mid, model.mesh_vert[va : va + vn], model.mesh_face[fa : fa + fn]


def build_visual_model(
    xml_path: str | Path, physics_model: Any, mesh_cell: float | None = 0.01, min_faces: int = 500
) -> Any:
    """A render-only copy of the model compiled from `xml_path`, meshes with >= `min_faces` faces simplified.

    The copy has the same bodies, joints, geoms, sites and cameras in the same order as `physics_model`
    (checked), so its state can be mirrored from the physics data. `mesh_cell=None` keeps the meshes.
    """
    import mujoco

    spec = mujoco.MjSpec.from_file(str(xml_path))
    if mesh_cell is not None:
        if mesh_cell <= 0:
            raise ValueError(f"mesh_cell must be > 0 metres or None, got {mesh_cell}")
        for sm, mid, v, f in large_meshes(spec, physics_model, min_faces):
            vert, face = decimate_mesh(v, f, mesh_cell)
            if len(face) >= 4:
                set_user_mesh(sm, physics_model, mid, vert, face)
    visual = spec.compile()
    for attr in ("nbody", "njnt", "nq", "ngeom", "nsite", "ncam", "nlight", "nmocap"):
        if getattr(visual, attr) != getattr(physics_model, attr):
            raise RuntimeError(
                f"the render-only model of {xml_path} differs from the physics model in {attr} "
                f"({getattr(visual, attr)} vs {getattr(physics_model, attr)}); pass mesh_cell=None"
            )
    return visual


def default_mesh_cell(height: int, width: int) -> float | None:
    """Mesh simplification that stays below a pixel: 1 cm up to 160 px, 5 mm up to 320 px, none above."""
    side = max(height, width)
    return 0.01 if side <= 160 else 0.005 if side <= 320 else None


def resolve_mesh_cell(mesh_cell: float | str | None, height: int, width: int) -> float | None:
    """An environment's `mesh_cell` argument -> the grid cell (metres) of the render copy's meshes, or None for
    the full meshes: "auto" is `default_mesh_cell`; ValueError for any other string."""
    cell = default_mesh_cell(height, width) if mesh_cell == "auto" else mesh_cell
    if isinstance(cell, str):
        raise ValueError(f"mesh_cell must be 'auto', a size in metres or None, got {mesh_cell!r}")
    return cell


@dataclass
class VisualMirror:
    """Keeps a render-only model/data pair in step with the physics model/data.

    `sync_model` copies what tasks change in the model at reset (body and site placements);
    `sync_data` copies the state (joint positions, mocap) and recomputes kinematics and cameras, then copies
    the site positions the task writes straight into the physics data (goal markers).
    """

    physics_model: Any
    visual_model: Any

    def __post_init__(self) -> None:
        import mujoco

        self._mj = mujoco
        self.visual_data = mujoco.MjData(self.visual_model)

    def sync_model(self) -> None:
        p, v = self.physics_model, self.visual_model
        v.body_pos[:] = p.body_pos
        v.body_quat[:] = p.body_quat
        v.site_pos[:] = p.site_pos
        v.site_quat[:] = p.site_quat

    def sync_data(self, physics_data: Any) -> Any:
        d = self.visual_data
        d.qpos[:] = physics_data.qpos
        d.mocap_pos[:] = physics_data.mocap_pos
        d.mocap_quat[:] = physics_data.mocap_quat
        self._mj.mj_kinematics(self.visual_model, d)
        self._mj.mj_camlight(self.visual_model, d)
        d.site_xpos[:] = physics_data.site_xpos
        d.site_xmat[:] = physics_data.site_xmat
        return d
