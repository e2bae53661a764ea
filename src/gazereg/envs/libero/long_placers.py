"""The placing halves of LIBERO-10's expert (`gazereg.envs.libero.expert_10`): a mug by its rim (`MugPlacer`), the
moka pot by its handle (`HandlePlacer`), any other item by its footprint with the placement's path clear too
(`ClearItemPlacer`), and the views of the scene a step's placer sees (`PlaceView`: its object and target as the
roles, every other object and fixture an obstacle; `AllObstacles`)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from gazereg.envs.libero.expert import (
    Plan,
    path_clearance,
    yawed,
)
from gazereg.envs.libero.expert_object import PALM_GRID, ItemShape
from gazereg.envs.libero.goal_placers import BowlPlacer, ItemPlacer
from gazereg.envs.libero.goal_scene import (
    GoalShifted,
    support_top,
)
from gazereg.envs.libero.scene import SUPPORTS, Boxes, TaskRoles


class MugPlacer(BowlPlacer):
    """A mug by its rim: BowlPlacer's grasp about the cup's centre (not the mug's origin), the handle's boxes
    an obstacle for the fingers, the pad centre `mug_grip_depth` under the rim (sizes from the mug's boxes)."""

    name = "gazereg.envs.libero.long_placers.MugPlacer"
    grip_depth = 0.022
    wall_in = 0.007
    handle_out = 0.012

    def _plan(self, env: Any, pts: dict[str, np.ndarray], boxes: Any) -> Plan:
        mug = env.scene_facts.geom_boxes(env.roles.obj)
        origin = pts["obj"]
        self._cup, radius, self._handle = cup_geometry(mug, origin, self.handle_out)
        top = float(mug.top().max())
        self.p = replace(
            self.p, rim_radius=radius - self.wall_in, grasp_height=top - float(origin[2]) - self.grip_depth
        )
        return super()._plan(env, pts, boxes)

    def _choose_grasp(self, bowl: np.ndarray, boxes: Any) -> tuple[np.ndarray, np.ndarray]:
        cup = np.array([*self._cup, 0.0])
        offset, rot = super()._choose_grasp(bowl + cup, Boxes.concat([boxes, self._handle]))
        return offset + cup, rot


def cup_geometry(boxes: Boxes, origin: np.ndarray, handle_out: float) -> tuple[np.ndarray, float, Boxes]:
    """A mug's cup from its collision boxes: (the cup's centre from `origin`, horizontal (2,); the wall's mean
    radius; the handle's boxes: those `handle_out` beyond the wall)."""
    xy = boxes.centre[:, :2]
    centre = np.median(xy, axis=0)
    for _ in range(3):
        d = np.linalg.norm(xy - centre, axis=1)
        wall = d > 0.5 * float(np.median(d[d > 0.015])) if (d > 0.015).any() else d >= 0
        radius = float(np.median(d[wall]))
        handle = d > radius + handle_out
        keep = ~handle
        centre = (xy[keep].max(axis=0) + xy[keep].min(axis=0)) / 2
    d = np.linalg.norm(xy - centre, axis=1)
    ring = (d > 0.015) & ~handle
    radius = float(np.median(d[ring])) if ring.any() else radius
    h = Boxes(boxes.centre[handle], boxes.rot[handle], boxes.half[handle])
    return centre - origin[:2], radius, h


class ClearItemPlacer(ItemPlacer):
    """ItemPlacer whose yaw also keeps the palm's path down at the placement free (the hand, 0.2 m long across
    the fingers, put down next to a mug already on its plate)."""

    name = "gazereg.envs.libero.long_placers.ClearItemPlacer"
    stall_steps = 8  # lowering, the hand this many steps within `stall` of where it was: the item rests
    stall = 0.002

    def _advance(self, reached: bool, pts: dict[str, np.ndarray]) -> bool:
        """PickPlaceExpert's, and lowering ends when the item has come to rest on something (the basket's
        wall, the item already there) before its release height: the hand stalls."""
        if self.phase != "lower":
            self._lowered: list[float] = []
        else:
            self._lowered.append(float(pts["hand"][2]))
            last = self._lowered[-self.stall_steps :]
            if len(self._lowered) > self.stall_steps and max(last) - min(last) < self.stall:
                reached = True
        return super()._advance(reached, pts)

    def _plan(self, env: Any, pts: dict[str, np.ndarray], boxes: Any) -> Plan:
        self._place_at = (env, pts)
        return super()._plan(env, pts, boxes)

    def _choose_yaw(self, shape: ItemShape, pad: float, boxes: Any) -> tuple[float, np.ndarray]:
        p = self.p
        env, pts = self._place_at
        goal, origin = pts["goal"], pts["obj"]
        surface = support_top(env, env.roles.goal, goal[:2])
        pad_place = surface + p.release_gap + (pad - shape.bottom)
        place_levels = np.arange(pad_place + p.palm_low, pad_place + p.palm_low + p.hover, 0.01)
        grasps = self._yaw_grasps(shape, pad, boxes)  # ObjectExpert's choice (its module docstring) ...
        keys = []
        for k, g in enumerate(grasps):  # ... the placement's palm path down clear too
            xy0 = goal[:2] + g.centre - origin[:2]
            xy = (
                xy0
                + PALM_GRID[:, :1] * p.palm_half[0] * g.along
                + PALM_GRID[:, 1:] * p.palm_half[1] * g.across
            )
            put, _ = path_clearance(boxes, xy, place_levels)
            keys.append(
                (
                    g.block > -np.inf,
                    g.width > p.max_width,
                    put > -np.inf,
                    g.block,
                    g.gap < p.min_gap,
                    round(g.width / p.width_step),
                    k,
                )
            )
        return self._take_yaw(keys, grasps)


class HandlePlacer(ClearItemPlacer):
    """An item with a handle sticking out of its body (the moka pot): held by the top of the handle, the fingers
    closing across it (the body's top is too wide and too low for the open fingers), put down as ItemPlacer."""

    name = "gazereg.envs.libero.long_placers.HandlePlacer"
    reach = 0.065  # a box whose centre is this far from the origin (horizontally) sticks out of the body
    pad_below = 0.01  # the pad centre this far under the handle's top

    def _plan(self, env: Any, pts: dict[str, np.ndarray], boxes: Any) -> Plan:
        plan = super()._plan(env, pts, boxes)  # the placing heights of ItemPlacer
        item = env.scene_facts.geom_boxes(env.roles.obj)
        grip = handle_grip(item, pts["obj"], self.reach)
        if grip is None:
            return plan
        point, yaw = grip
        p, origin = self.p, pts["obj"]
        pad = point[2] - self.pad_below
        above = pad - float(origin[2])
        self.grasp_choice = {"yaw_deg": float(yaw), "handle": 1.0}
        offset = np.array([point[0] - origin[0], point[1] - origin[1], above])
        bounds = (above - p.hand_play, above + p.hand_play)
        return Plan(offset, yawed(yaw), pad - ItemShape.of(item).bottom, above, bounds, plan.place_dz)


def handle_grip(boxes: Boxes, origin: np.ndarray, reach: float) -> tuple[np.ndarray, float] | None:
    """The top of an item's handle: (the point over the box with the highest top among those on the side of the
    box farthest from the origin, at that top (3,); the gripper yaw (degrees, in (-90, 90]) whose fingers close
    across the handle), or None when no box's centre is `reach` from the origin (horizontally)."""
    rel = boxes.centre[:, :2] - origin[:2]
    dist = np.linalg.norm(rel, axis=1)
    if not (dist > reach).any():
        return None
    h = rel[int(np.argmax(dist))] / float(dist.max())  # towards the handle's far end
    on = (rel @ h) > 0.6 * reach
    k = np.flatnonzero(on)[int(np.argmax(boxes.top()[on]))]
    point = np.array([*boxes.centre[k, :2], float(boxes.top()[k])])
    # closing across the handle, along (-h_y, h_x): yawed(yaw) closes along (-sin yaw, cos yaw)
    yaw = float(np.degrees(np.arctan2(h[1], h[0])))
    return point, -(((-yaw) + 90.0) % 180.0 - 90.0)  # the fingers are symmetric


class PlaceView(GoalShifted):
    """`env` as one placement step sees it: roles (obj, goal, relation) of the step, `key_points()` of those (the
    goal moved by `shift`), the obstacles every object and fixture but the step's object."""

    def __init__(self, env: Any, obj: str, goal: str, relation: str, shift: np.ndarray):
        super().__init__(env, shift)
        self.roles = TaskRoles(obj=obj, goal=goal, relation=relation)
        self.scene_facts = _Facts(env, obj)

    def key_points(self) -> dict[str, np.ndarray]:
        f = self._env.scene_facts
        return {
            "obj": f.position(self.roles.obj),
            "goal": f.position(self.roles.goal) + self._shift,
            "hand": f.hand(),
        }


class _Facts:
    """`env.scene_facts` with the obstacles every object and fixture but `obj` (None: all of them)."""

    def __init__(self, env: Any, obj: str | None):
        self._env, self._facts, self._obj = env, env.scene_facts, obj

    def __getattr__(self, name: str) -> Any:
        return getattr(self._facts, name)

    def owner(self, name: str) -> str:
        """As SceneFacts.owner; a region of the table itself (no parent object: `..._plate_right_region`):
        itself (`geom_boxes` gives its flat box)."""
        o = self._facts.owner(name)
        return o if o in self._env.unwrapped_libero.env.obj_body_id else name

    def geom_boxes(self, name: str) -> Boxes:
        """As SceneFacts.geom_boxes; a region of the table itself: its site's box, flat (no thickness)."""
        e = self._env.unwrapped_libero.env
        if name in e.obj_body_id:
            return self._facts.geom_boxes(name)
        size = np.asarray(e.object_sites_dict[name].size, dtype=np.float64)
        M = np.asarray(e.sim.data.get_site_xmat(name), dtype=np.float64)
        return Boxes(self._facts.position(name)[None], M[None], np.array([[size[0], size[1], 0.0]]))

    def obstacles(self) -> Boxes:
        e = self._env.unwrapped_libero.env
        names = [n for n in (*e.objects_dict, *e.fixtures_dict) if not _support(n) and n != self._obj]
        return Boxes.concat([self._facts.geom_boxes(n) for n in names if n in e.obj_body_id])


class AllObstacles(GoalShifted):
    """`env` with every object an obstacle (for the pull, turn and close steps)."""

    def __init__(self, env: Any):
        super().__init__(env, np.zeros(3))
        self.scene_facts = _Facts(env, None)


def _support(name: str) -> bool:
    """A table or the floor (LIBERO's SUPPORTS, and LIBERO-10's `living_room_table`, `study_table`, ...): what
    objects stand on, not an obstacle."""
    return name in SUPPORTS or name.endswith("_table")
