"""The LIBERO-Goal kitchen as its expert reads it (`gazereg.envs.libero.expert_goal`): joints, the collision
boxes of a body, support surfaces under a point, the regions' targets and the gripper frames (world, metres,
radians)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from gazereg.envs.libero.scene import Boxes, collision_boxes, subtree_geoms


@dataclass(frozen=True)
class Joint:
    """A hinge or slide joint of the scene: MuJoCo id, its body, qpos address, world axis (3,), anchor (3,)."""

    id: int
    body: int
    qpos: int
    axis: np.ndarray
    anchor: np.ndarray

    @staticmethod
    def named(env: Any, name: str) -> Joint:
        import mujoco

        m, d = env.physics_model, env.physics_data
        j = int(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name))
        if j < 0:
            raise KeyError(f"joint {name!r} is not in the model of {env.task!r}")
        return Joint(j, int(m.jnt_bodyid[j]), int(m.jnt_qposadr[j]), d.xaxis[j].copy(), d.xanchor[j].copy())

    def value(self, env: Any) -> float:
        return float(env.physics_data.qpos[self.qpos])


def body_geoms(env: Any, body: int) -> np.ndarray:
    """Ids of the geoms of MuJoCo body `body` alone."""
    return np.flatnonzero(np.asarray(env.physics_model.geom_bodyid) == body)


def body_boxes(env: Any, body: int) -> Boxes:
    """The oriented boxes around the collision geoms of MuJoCo body `body` alone (world, metres)."""
    return collision_boxes(env.physics_model, env.physics_data, body_geoms(env, body))


def frame(approach: np.ndarray, closing: np.ndarray) -> np.ndarray:
    """The gripper orientation (3, 3) (columns: the gripper's axes, as DOWN_ALONG_Y) pointing along `approach`
    with the fingers closing along `closing` (unit vectors, perpendicular)."""
    return np.stack([closing, np.cross(approach, closing), approach], axis=1)


def rot_z(angle: float) -> np.ndarray:
    """A rotation by `angle` radians about the world's vertical (3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def goal_predicates(env: Any) -> list[list[str]]:
    """The task's goal predicates, predicate names lower-cased: [["open", "wooden_cabinet_1_top_region"]]."""
    goal = env.unwrapped_libero.env.parsed_problem.get("goal_state", [])
    return [[str(p[0]).lower(), *map(str, p[1:])] for p in goal]


def drawer_joints(env: Any, region: str) -> list[str]:
    """The slide joints of `region` when it is a drawer's region (its site names them); [] for any other name."""
    site = env.unwrapped_libero.env.object_sites_dict.get(region)
    return list(getattr(site, "joints", None) or [])


def region_body(env: Any, region: str) -> int:
    """The MuJoCo body id of the body that `region`'s site is attached to."""
    import mujoco

    m = env.physics_model
    return int(m.site_bodyid[int(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, region))])


def support_top(env: Any, name: str, xy: np.ndarray) -> float:
    """The highest top (z, metres) among the collision boxes of `name` (a region: its site's body and the bodies
    below it; an object or fixture: its own) whose footprint holds the point `xy` (2,); `name`'s own z if
    none does."""
    m = env.physics_model
    facts = env.scene_facts
    e = env.unwrapped_libero.env
    if name in e.object_sites_dict:
        root = region_body(env, name)
    else:
        root = int(e.obj_body_id[facts.owner(name)])
    boxes = collision_boxes(m, env.physics_data, subtree_geoms(m, root))
    if not len(boxes):
        return float(facts.position(name)[2])
    tops = line_tops(boxes, xy)
    return float(np.nanmax(tops)) if np.isfinite(tops).any() else float(facts.position(name)[2])


def line_tops(boxes: Boxes, xy: np.ndarray) -> np.ndarray:
    """(n,) where the vertical line through `xy` (2,) leaves each box at the top (z, metres; NaN: it misses the
    box): a slanted board's surface at that point, not its highest corner."""
    # in each box's frame the line is a + t b (t: world z); |a + t b| <= half per axis bounds t
    a = np.einsum("nji,nj->ni", boxes.rot, np.append(xy, 0.0)[None] - boxes.centre)  # (n, 3)
    b = boxes.rot[:, 2, :]  # (n, 3): the world's z axis in each box's frame
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-boxes.half - a) / b, (boxes.half - a) / b
    lo, hi = np.minimum(t1, t2), np.maximum(t1, t2)
    flat = np.abs(b) < 1e-12  # the line runs parallel to this face pair: inside or not, whatever t
    inside_flat = np.abs(a) <= boxes.half + 1e-9
    lo = np.where(flat, np.where(inside_flat, -np.inf, np.inf), lo)
    hi = np.where(flat, np.where(inside_flat, np.inf, -np.inf), hi)
    t_lo, t_hi = lo.max(axis=1), hi.min(axis=1)
    return np.where(t_lo <= t_hi, t_hi, np.nan)


def corridor_top(boxes: Boxes, a: np.ndarray, b: np.ndarray, corridor: float) -> float:
    """The highest top (z, metres) of the boxes whose footprint (world-aligned bounding rectangle) comes within
    `corridor` (horizontally) of the segment a -> b (3,); the higher end's z without any. Unlike
    `PickPlaceExpert._corridor_top` (a disc around each box), a long thin board beside the path is not near
    it."""
    if not len(boxes):
        return float(max(a[2], b[2]))
    c = boxes.corners().reshape(-1, 8, 3)
    lo, hi = c[:, :, :2].min(axis=1), c[:, :, :2].max(axis=1)  # (n, 2)
    n = max(2, int(np.ceil(np.linalg.norm(b[:2] - a[:2]) / 0.01)) + 1)
    path = a[:2] + np.linspace(0.0, 1.0, n)[:, None] * (b[:2] - a[:2])  # (n, 2)
    gap = np.maximum(np.maximum(lo[None] - path[:, None], path[:, None] - hi[None]), 0.0)  # (n, boxes, 2)
    near = np.linalg.norm(gap, axis=-1).min(axis=0) < corridor
    return float(boxes.top()[near].max()) if near.any() else float(max(a[2], b[2]))


def region_shift(env: Any, goal: str, rise: float) -> np.ndarray:
    """Where to put an object down `On` region `goal`, from the region's site (3,), horizontal (`In` a region
    tests a box centred on the site: no shift there). LIBERO's test (`SiteObject.under`) takes the object's
    origin within the site's box in the site's own frame, up to 0.1 above its top face along the site's z axis;
    the point `rise` above that face is the target. Zero for a level
    region (its z axis vertical), an object or a fixture; a slanted one (the wine rack's top board) moves it
    up the slope."""
    site = env.unwrapped_libero.env.object_sites_dict.get(goal)
    if site is None or not hasattr(site, "under"):
        return np.zeros(3)
    M = np.asarray(env.unwrapped_libero.env.sim.data.get_site_xmat(goal), dtype=np.float64)
    d = M.T @ np.array([0.0, 0.0, float(np.asarray(site.size)[2]) + rise])  # `under` reads M @ d
    return np.array([d[0], d[1], 0.0])


class GoalShifted:
    """`env` as a placing plan sees it: `key_points()["goal"]` moved by `shift` (3,), all else `env`'s."""

    def __init__(self, env: Any, shift: np.ndarray):
        self._env, self._shift = env, shift

    def __getattr__(self, name: str) -> Any:
        return getattr(self._env, name)

    def key_points(self) -> dict[str, np.ndarray]:
        pts = self._env.key_points()
        pts["goal"] = pts["goal"] + self._shift
        return pts
