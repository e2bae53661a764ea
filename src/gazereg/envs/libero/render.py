"""A render-only copy of a LIBERO task's model with simplified meshes, textures kept (for `LiberoEnv`).

    visual = build_libero_visual_model(xml, physics_model, mesh_cell=0.005)   # compile once per task
    sync_appearance(physics_model, visual)                                     # after robosuite's resets

Why. LIBERO's scenes carry about 300k mesh triangles (the Panda's visual meshes, the objects, the furniture);
drawing them is most of a step's time at 128 px on a CPU (Mesa llvmpipe). As in `gazereg.envs.render` for
Meta-World, the render copy simplifies every mesh of at least `min_faces` faces by vertex clustering on a grid
of `mesh_cell` metres; unlike Meta-World's objects, many of LIBERO's meshes are textured, so each surviving
triangle keeps the texture coordinates of the original triangle it came from (MuJoCo indexes texture
coordinates per face, independently of the vertices), and untextured meshes are simplified as before.

Physics never sees the copy: `gazereg.envs.render.VisualMirror` mirrors the state into it before each render.
robosuite changes a few appearance fields of the compiled physics model at runtime (it hides some sites by
setting their alpha); `sync_appearance` copies those into the copy.
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gazereg.envs.render import cluster_vertices, drop_unused, large_meshes, nondegenerate, set_user_mesh

# Model fields robosuite/LIBERO set on the compiled model after compiling (appearance only).
APPEARANCE_FIELDS = ("site_rgba", "site_size", "geom_rgba", "mat_rgba")
# Other names of LIBERO's two cameras: short ones, and the HDF5 observation keys `gazereg import hdf5` names the
# cameras of LIBERO's (agentview_rgb, eye_in_hand_rgb) and robomimic's (*_image) files after.
CAMERA_ALIASES = {
    "wrist": "robot0_eye_in_hand",
    "eye_in_hand": "robot0_eye_in_hand",
    "eye_in_hand_rgb": "robot0_eye_in_hand",
    "robot0_eye_in_hand_image": "robot0_eye_in_hand",
    "agentview_rgb": "agentview",
    "agentview_image": "agentview",
}
COLLISION_GROUP = 0  # robosuite's geom group of collision geoms (visual geoms are group 1)


def decimate_with_texcoords(
    vert: np.ndarray, face: np.ndarray, facetex: np.ndarray | None, cell: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
    """Vertex clustering on a grid of `cell` metres, keeping each surviving face's texture-coordinate indices.

    vert (V, 3), face (F, 3) int, facetex (F, 3) int or None -> vert (V', 3) float64, face (F', 3) int64,
    facetex (F', 3) int64 or None, kept (F',) int64 (the original face of each surviving one): vertices in
    one grid cube merge (their mean), faces that collapse are dropped, and of faces that become identical the
    first is kept (with its own texture coordinates)."""
    merged, inv = cluster_vertices(vert, cell)
    f = inv[np.asarray(face)]
    keep = np.flatnonzero(nondegenerate(f))
    _, first = np.unique(np.sort(f[keep], axis=1), axis=0, return_index=True)
    keep = keep[np.sort(first)]
    vert_out, face_out = drop_unused(merged, f[keep])
    ft = None if facetex is None else np.asarray(facetex, dtype=np.int64)[keep]
    return vert_out, face_out, ft, keep


def build_libero_visual_model(
    xml_path: str | Path,
    physics_model: Any,
    mesh_cell: float,
    min_faces: int = 500,
    relative_cell: float = 1 / 40,
) -> Any:
    """Compile `xml_path` (the XML robosuite compiled `physics_model` from) with its meshes of >= `min_faces`
    faces simplified, texture coordinates kept. A mesh's grid cell is `mesh_cell` metres, or `relative_cell`
    of its largest extent when that is smaller (the small task objects keep their shape: a bowl is 42k
    triangles in 11 cm). Same bodies, geoms, cameras, lights in the same order as `physics_model` (checked)."""
    import mujoco

    if not mesh_cell > 0:
        raise ValueError(f"mesh_cell must be > 0 metres, got {mesh_cell}")
    m = physics_model
    spec = mujoco.MjSpec.from_file(str(xml_path))
    for sm, mid, v, f in large_meshes(spec, m, min_faces):
        fa, fn = m.mesh_faceadr[mid], m.mesh_facenum[mid]
        ta, tn = m.mesh_texcoordadr[mid], m.mesh_texcoordnum[mid]
        facetex = m.mesh_facetexcoord[fa : fa + fn] if tn > 0 else None
        cell = min(mesh_cell, relative_cell * float((v.max(axis=0) - v.min(axis=0)).max()))
        vert, face, ft, _ = decimate_with_texcoords(v, f, facetex, cell)
        if len(face) < 4:
            continue
        # Normals are recomputed by the compiler (the compiled ones did not carry over: measured worse).
        texcoord = m.mesh_texcoord[ta : ta + tn] if ft is not None else None
        set_user_mesh(sm, m, mid, vert, face, texcoord, ft)
    visual = spec.compile()
    for attr in ("nbody", "njnt", "nq", "ngeom", "nsite", "ncam", "nlight", "nmat", "ntex"):
        if getattr(visual, attr) != getattr(m, attr):
            raise RuntimeError(
                f"the render copy of {xml_path} differs from the physics model in {attr} "
                f"({getattr(visual, attr)} vs {getattr(m, attr)}); use mesh_cell=None"
            )
    sync_appearance(m, visual)
    return visual


def sync_appearance(physics_model: Any, visual_model: Any) -> None:
    """Copy the appearance fields robosuite changes at runtime (APPEARANCE_FIELDS) into the render copy."""
    for name in APPEARANCE_FIELDS:
        getattr(visual_model, name)[:] = getattr(physics_model, name)


def compile_render_copy(xml: str, physics_model: Any, mesh_cell: float) -> Any:
    """`build_libero_visual_model` from the XML text robosuite compiled `physics_model` from (absolute asset
    paths), written to a temporary file."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "libero_task.xml"
        path.write_text(xml)
        return build_libero_visual_model(path, physics_model, mesh_cell=float(mesh_cell))


def camera_ids(model: Any, cameras: Sequence[str]) -> dict[str, int]:
    """Each camera name (or alias, CAMERA_ALIASES) -> its camera id in `model`; KeyError names the model's."""
    import mujoco

    ids = {}
    for cam in cameras:
        cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, CAMERA_ALIASES.get(cam, cam))
        if cid < 0:
            names = [model.camera(i).name for i in range(model.ncam)]
            raise KeyError(f"no camera {cam!r} in LIBERO's model; cameras: {names}")
        ids[cam] = cid
    return ids
