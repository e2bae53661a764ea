"""A scripted expert for LIBERO-Object: pick up a grocery item and place it in the basket.

    env = LiberoEnv("libero_object/3", cameras=())
    expert = ObjectExpert(noise=0.0)
    obs, info = env.reset(seed=2)
    expert.reset(env, noise_seed=[2, 0])
    action = expert(env)                    # float32 (7,) in [-1, 1], LIBERO's OSC_POSE action

Every LIBERO-Object task is `(In <item> basket_1_contain_region)`: the item (a can, a carton, a bottle, a box of
cream cheese or butter) must rest inside the basket. The expert is `PickPlaceExpert`'s phase machine (above,
descend, close, lift, carry, lower, open, retreat; `gazereg.envs.libero.expert`) with its own plan:

Grasp. From the item's collision geoms (`SceneFacts.geom_boxes`: each geom's box, in the world) the expert
takes the item's bottom, top and, for each gripper yaw of YAWS, its width along the fingers' closing axis and
the centre of its footprint. The pad centre goes `grasp_frac` of the item's height above its bottom (at
least `min_pad`, so the fingertips clear the table under a flat box, and `top_margin` under its top, but
no more than `palm_room` under it, so that the palm stays above a tall bottle, which is taken by its neck),
over the footprint's centre. The yaw: the first of YAWS (least turn first) whose two open fingers' paths down
(a grid over each finger's footprint, `finger_reach` from the centre, from `hover` above the grasp to the
tips) and the palm's (`palm_half` about the centre, from `palm_low` above the pad centre up: it is 0.2 m
long along the closing axis and catches a tall neighbour) are free of the obstacle boxes (`SceneFacts.obstacles`: the other items and the basket), preferring
items no wider than `max_width` there, paths at least `min_gap` from every obstacle, and the narrowest width
(in steps of `width_step`): a box of cream cheese is taken across, a can from wherever the hand comes.

Placement. The goal point is the basket's contain region (its site); the item's origin is carried over it,
above the basket's walls (`clearance` under the item's bottom), then lowered until its bottom is
`release_gap` above the basket's floor (the lowest top among the basket's collision boxes), and released.

Measured success: `benchmarks/bench_libero.py --suite libero_object --expert-inits N` (docs/benchmarks/).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from gazereg.envs.libero.expert import MotionParams, PickPlaceExpert, Plan, path_clearance, yawed

# Gripper yaws about the vertical from DOWN_ALONG_Y (degrees), least turn first; the fingers are symmetric, so
# (-90, 90] covers every closing axis.
YAWS = (0, 15, -15, 30, -30, 45, -45, 60, -60, 75, -75, 90)


@dataclass(frozen=True)
class ObjectParams(MotionParams):
    """The LIBERO-Object expert's (metres); defaults fit LIBERO's grocery items and the Panda gripper."""

    tip_depth: float = 0.02  # the fingertips below the pad centre (0.017 for the Panda) plus a margin
    release_gap: float = 0.02  # the item's bottom above the basket's floor when opening
    grasp_frac: float = 0.5  # the pad centre this fraction of the item's height above its bottom
    min_pad: float = 0.016  # the pad centre at least this above the item's bottom (the tips clear the table)
    top_margin: float = 0.01  # and at least this below its top
    palm_room: float = 0.016  # and at most this below it: the palm sits 0.02 above the pad centre
    finger_reach: float = 0.048  # an open finger's footprint centre from the grasp centre (pads 0.084 apart)
    finger_half: tuple[float, float] = (0.012, 0.015)  # its footprint's half sizes (along, across), margin in
    palm_half: tuple[float, float] = (0.105, 0.034)  # the palm's footprint (along, across the closing axis)
    palm_low: float = 0.02  # the palm's bottom above the pad centre
    max_width: float = 0.07  # the widest item (along the closing axis) the open fingers take with a margin
    width_step: float = 0.005  # widths this close count as equal (the smaller turn wins)
    descend_speed: float = 0.4  # a fast descent drifts the hand sideways onto a wide can's rim
    hand_play: float = 0.03  # the held item's height in the hand within this of the planned one


@dataclass(frozen=True)
class ItemShape:
    """An item's collision geometry in the world: corners (k, 3) of its boxes, bottom and top z (metres)."""

    corners: np.ndarray
    bottom: float
    top: float

    @staticmethod
    def of(boxes: Any) -> ItemShape:
        corners = boxes.corners()
        return ItemShape(corners, float(corners[:, 2].min()), float(corners[:, 2].max()))

    def footprint(self, yaw_deg: float) -> tuple[float, np.ndarray]:
        """(width along the closing axis of gripper yaw `yaw_deg`, centre (2,) of the footprint's extent)."""
        a, perp = closing_axes(yaw_deg)
        along, across = self.corners[:, :2] @ a, self.corners[:, :2] @ perp
        centre = a * (along.max() + along.min()) / 2 + perp * (across.max() + across.min()) / 2
        return float(along.max() - along.min()), centre


FINGER_GRID = np.array([(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1)], dtype=np.float64)
"""(9, 2) points across a fingertip's pad, in units of its half extents (along, across the closing axis)"""
PALM_GRID = np.array([(i, j) for i in (-1, -0.5, 0, 0.5, 1) for j in (-1, 0, 1)], dtype=np.float64)
"""(15, 2) points across the palm, in units of its half extents"""


class YawGrasp(NamedTuple):
    """One of YAWS's grasps of an item (`ObjectExpert._yaw_grasps`)."""

    width: float
    """the item's footprint across the closing axis, metres"""
    centre: np.ndarray
    """(2,) the footprint's centre, world"""
    along: np.ndarray
    """(2,) the closing axis (`closing_axes`)"""
    across: np.ndarray
    """(2,) perpendicular to it"""
    block: float
    """the highest top blocking the fingers' or palm's path down, -inf if none (`path_clearance`)"""
    gap: float
    """the narrowest gap to the boxes beside the path"""


def closing_axes(yaw_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """The fingers' closing axis (2,) of gripper yaw `yaw_deg` (the columns of `yawed`) and its perpendicular."""
    a = np.array([-np.sin(np.radians(yaw_deg)), np.cos(np.radians(yaw_deg))])
    return a, np.array([-a[1], a[0]])


class ObjectExpert(PickPlaceExpert):
    """The LIBERO-Object expert (see the module docstring): an item, by its footprint's centre, into the basket."""

    name = "gazereg.envs.libero.expert_object.ObjectExpert"
    relation = "in"
    params_type = ObjectParams

    def _plan(self, env: Any, pts: dict[str, np.ndarray], boxes: Any) -> Plan:
        p, facts = self.p, env.scene_facts
        shape = ItemShape.of(facts.geom_boxes(env.roles.obj))
        height = shape.top - shape.bottom
        pad = shape.bottom + max(
            min(p.grasp_frac * height, height - p.top_margin), p.min_pad, height - p.palm_room
        )
        yaw, centre = self._choose_yaw(shape, pad, boxes)
        origin = pts["obj"]
        above = pad - float(origin[2])
        # The container's floor: the lowest top among its collision boxes (the basket's walls stand higher).
        floor = float(facts.geom_boxes(facts.owner(env.roles.goal)).top().min())
        place_dz = floor + p.release_gap + (float(origin[2]) - shape.bottom) - float(pts["goal"][2])
        offset = np.array([centre[0] - origin[0], centre[1] - origin[1], above])
        return Plan(
            offset,
            yawed(yaw),
            pad - shape.bottom,
            above,
            (above - p.hand_play, above + p.hand_play),
            place_dz,
        )

    def _yaw_grasps(self, shape: ItemShape, pad: float, boxes: Any) -> list[YawGrasp]:
        """Each of YAWS's grasps of `shape` with the pad centre at height `pad` (metres, world): its footprint,
        closing axes, and how the fingers' and the palm's paths down clear `boxes` (`path_clearance`)."""
        p = self.p
        levels = np.arange(pad - p.tip_depth, pad + p.hover, 0.01)
        palm_levels = np.arange(pad + p.palm_low, pad + p.palm_low + p.hover, 0.01)
        grasps = []
        for yaw in YAWS:
            width, centre = shape.footprint(yaw)
            a, perp = closing_axes(yaw)
            paths = [
                (centre + side * p.finger_reach * a, FINGER_GRID, p.finger_half, levels)
                for side in (1.0, -1.0)
            ] + [(centre, PALM_GRID, p.palm_half, palm_levels)]
            block, gap = -np.inf, np.inf
            for xy0, g, half, zs in paths:
                xy = xy0 + g[:, :1] * half[0] * a + g[:, 1:] * half[1] * perp
                b, d = path_clearance(boxes, xy, zs)
                block, gap = max(block, b), min(gap, d)
            grasps.append(YawGrasp(width, centre, a, perp, block, gap))
        return grasps

    def _take_yaw(self, keys: list[tuple[Any, ...]], grasps: list[YawGrasp]) -> tuple[float, np.ndarray]:
        """The grasp whose key (ending in its index into YAWS) is the least: (yaw, degrees; its centre (2,))."""
        k = min(keys)[-1]
        self.grasp_choice = {"yaw_deg": float(YAWS[k]), "width": float(grasps[k].width)}
        return float(YAWS[k]), grasps[k].centre

    def _choose_yaw(self, shape: ItemShape, pad: float, boxes: Any) -> tuple[float, np.ndarray]:
        """(gripper yaw, degrees; the grasp centre (2,), world): see the module docstring's Grasp."""
        p = self.p
        grasps = self._yaw_grasps(shape, pad, boxes)
        keys = [
            (
                g.block > -np.inf,
                g.width > p.max_width,
                g.block,
                g.gap < p.min_gap,
                round(g.width / p.width_step),
                k,
            )
            for k, g in enumerate(grasps)
        ]
        return self._take_yaw(keys, grasps)
