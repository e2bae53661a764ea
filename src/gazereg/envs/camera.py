"""Camera geometry: which way up an image is, and where world points land in it.

This object owns the only transform between MuJoCo's raw render and the image the policy sees: an optional
180-degree rotation. MuJoCo's camera frame has x to the right, y up and looks along -z; a camera whose
image-up axis points downward in the world (Meta-World's `corner`, `corner2`, `corner3`, `corner4`) renders
the scene upside down, so its images are rotated by 180 degrees (`rot180`), and so are projected points.

Projection (pinhole, square pixels, principal point at the image centre, as MuJoCo renders):
    p_cam = R^T (p_world - cam_pos)          R = cam_xmat (columns: camera x, y, z in the world)
    f     = 0.5 * H / tan(fovy / 2)           fovy: the camera's vertical field of view
    x_px  = W / 2 + f * p_cam.x / (-p_cam.z)  y_px = H / 2 - f * p_cam.y / (-p_cam.z)
    (u, v) = (x_px / W, y_px / H)             normalised, u right, v down; pixel j covers [j, j + 1)
    rot180: (u, v) -> (1 - u, 1 - v)
Points behind the camera get NaN. Points outside the image keep their values outside [0, 1].
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

# A camera whose image-up axis has a world-z component below this is upside down.
_UP_THRESHOLD = -1e-6


def needs_rot180(cam_xmat: np.ndarray) -> bool:
    """True when the camera's image-up axis (its y axis) points downward in the world."""
    return bool(np.asarray(cam_xmat, dtype=np.float64).reshape(3, 3)[2, 1] < _UP_THRESHOLD)


@dataclass(frozen=True)
class CameraGeometry:
    """One camera's image geometry as the policy sees it: size, field of view and orientation."""

    name: str
    height: int
    width: int
    fovy_deg: float
    rot180: bool

    @property
    def focal_px(self) -> float:
        return 0.5 * self.height / math.tan(math.radians(self.fovy_deg) / 2)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def project(self, points: np.ndarray, cam_pos: np.ndarray, cam_xmat: np.ndarray) -> np.ndarray:
        """World points (..., 3) -> normalised (u, v) (..., 2) in the policy's image; NaN behind the camera."""
        pts = np.asarray(points, dtype=np.float64)
        R = np.asarray(cam_xmat, dtype=np.float64).reshape(3, 3)
        pc = (pts - np.asarray(cam_pos, dtype=np.float64)) @ R  # rows: R^T (p - c)
        depth = -pc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x_px = 0.5 * self.width + self.focal_px * pc[..., 0] / depth
            y_px = 0.5 * self.height - self.focal_px * pc[..., 1] / depth
        uv = np.stack([x_px / self.width, y_px / self.height], axis=-1)
        uv[depth <= 0] = np.nan
        if self.rot180:
            uv = 1.0 - uv
        return uv

    def orient(self, upright_raw: np.ndarray) -> np.ndarray:
        """The policy's image: a new contiguous copy of an image (..., H, W, C) rendered top row first, rotated
        by 180 degrees when this camera needs it."""
        x = upright_raw[..., ::-1, ::-1, :] if self.rot180 else upright_raw
        return np.array(x, order="C", copy=True)

    def uv_to_pixel(self, uv: np.ndarray) -> np.ndarray:
        """Normalised (u, v) -> integer pixel indices (row, col) (..., 2), clipped to the image."""
        uv = np.asarray(uv, dtype=np.float64)
        col = np.clip(np.floor(uv[..., 0] * self.width), 0, self.width - 1)
        row = np.clip(np.floor(uv[..., 1] * self.height), 0, self.height - 1)
        return np.stack([row, col], axis=-1).astype(np.int64)


def camera_geometry(model: Any, data: Any, camera: str, height: int, width: int) -> CameraGeometry:
    """The geometry of a named camera of a MuJoCo model in its current pose (data after kinematics)."""
    import mujoco

    cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
    if cid < 0:
        names = [model.camera(i).name for i in range(model.ncam)]
        raise KeyError(f"no camera {camera!r} in the model; cameras: {names}")
    return CameraGeometry(
        name=camera,
        height=int(height),
        width=int(width),
        fovy_deg=float(model.cam_fovy[cid]),
        rot180=needs_rot180(data.cam_xmat[cid]),
    )
