"""The placing halves of LIBERO-Goal's expert (`gazereg.envs.libero.expert_goal`): a bowl by its rim
(`BowlPlacer`, SpatialExpert's grasp with the palm's path tested too) and any other item by its footprint
(`ItemPlacer`, ObjectExpert's grasp), each put down on the support surface of the task's target."""

from __future__ import annotations

from typing import Any

import numpy as np

from gazereg.envs.libero.expert import (
    CANDIDATES,
    Plan,
    SpatialExpert,
    path_clearance,
    yawed,
)
from gazereg.envs.libero.expert_object import ItemShape, ObjectExpert, ObjectParams, closing_axes
from gazereg.envs.libero.goal_scene import corridor_top, line_tops, support_top
from gazereg.envs.libero.scene import Boxes

# The Panda palm's footprint (half sizes along and across the closing axis) and its bottom above the pad centre
# (ObjectParams' defaults), for the bowl's grasp.
PALM_HALF, PALM_LOW = ObjectParams.palm_half, ObjectParams.palm_low
PALM_TALL = 0.2  # the hand and the wrist above the palm's bottom, what an overhang must clear


class BowlPlacer(SpatialExpert):
    """A bowl, by its rim (SpatialExpert's grasp, the palm's path tested too), onto or into any target (the
    relation is the task's); a bowl under an overhang (the open drawer) is lifted up and out sideways."""

    name = "gazereg.envs.libero.expert_goal.BowlPlacer"
    escape_margin = 0.015  # the footprint's margin under an overhang, slid this much beyond its edge

    def reset(self, env: Any, noise_seed: Any = 0) -> None:
        self.relation = env.roles.relation
        super().reset(env, noise_seed)

    def _plan(self, env: Any, pts: dict[str, np.ndarray], boxes: Any) -> Plan:
        # the overhang first: the grasp prefers the side the bowl escapes towards
        self.escape = self._overhang_escape(env, pts["obj"], boxes)
        plan = super()._plan(env, pts, boxes)
        if self.escape is not None:
            self.grasp_choice["escape"] = [float(x) for x in self.escape]
        bottom = float(env.scene_facts.geom_boxes(env.roles.obj).corners()[:, 2].min())
        surface = support_top(env, env.roles.goal, pts["goal"][:2])
        plan.place_dz = surface + self.p.release_gap + (float(pts["obj"][2]) - bottom) - float(pts["goal"][2])
        return plan

    escape: np.ndarray | None = None  # (2,) world: the lift's sideways move out from under an overhang
    exact_corridor = False  # heights from `corridor_top` (set when time is short), else PickPlaceExpert's

    def _corridor_top(self, boxes: Any, a: np.ndarray, b: np.ndarray) -> float:
        if self.exact_corridor:
            return corridor_top(boxes, a, b, self.p.corridor)
        return super()._corridor_top(boxes, a, b)

    def _target(self, pts: dict[str, np.ndarray]) -> tuple[np.ndarray, float]:
        target, grip = super()._target(pts)
        if self.phase == "lift" and self.escape is not None and self._hold is not None:
            target[:2] = self._hold[:2] + self.escape  # up and out at once
        return target, grip

    def _overhang_escape(self, env: Any, bowl: np.ndarray, boxes: Boxes) -> np.ndarray | None:
        """The horizontal move (2,) that takes the bowl's footprint out from under the obstacle boxes above
        its top (an open drawer over it), or None when nothing hangs over it."""
        shape = ItemShape.of(env.scene_facts.geom_boxes(env.roles.obj))
        radius = float(np.max(np.linalg.norm(shape.corners[:, :2] - bowl[:2], axis=1))) + self.escape_margin
        high = boxes.corners().reshape(-1, 8, 3)[:, :, 2].min(axis=1) > shape.top
        if not high.any():
            return None
        over = Boxes(boxes.centre[high], boxes.rot[high], boxes.half[high])
        g = np.linspace(-radius, radius, 21)
        disc = np.array([(x, y) for x in g for y in g if x * x + y * y <= radius * radius]) + bowl[:2]
        covered = np.array([np.isfinite(line_tops(over, q)).any() for q in disc])
        if not covered.any():
            return None
        u = bowl[:2] - disc[covered].mean(axis=0)
        u = u / max(float(np.linalg.norm(u)), 1e-9)
        dist = float(np.max(radius - (disc[covered] - bowl[:2]) @ u)) + self.escape_margin
        return u * dist

    def _choose_grasp(self, bowl: np.ndarray, boxes: Any) -> tuple[np.ndarray, np.ndarray]:
        """SpatialExpert's choice (see its docstring) with the palm's path down tested too (an open drawer
        hangs over a bowl next to the cabinet): the palm's footprint, PALM_HALF about the grasp point, from
        PALM_LOW above the pad centre up by PALM_TALL, must be free as well. Under an overhang (`escape`) a
        grasp on the side the bowl escapes towards comes first."""
        p = self.p
        grasp_z = bowl[2] + p.grasp_height
        levels = np.arange(grasp_z - p.tip_depth, grasp_z + p.hover, 0.01)
        palm_levels = np.arange(grasp_z + PALM_LOW, grasp_z + PALM_LOW + PALM_TALL, 0.01)
        grid = np.array([(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1)], dtype=np.float64)
        palm_grid = np.array([(i, j) for i in (-1, -0.5, 0, 0.5, 1) for j in (-1, 0, 1)], dtype=np.float64)
        keys = []
        for k, (yaw, side) in enumerate(CANDIDATES):
            a, perp = closing_axes(yaw)
            finger = bowl[:2] + side * (p.rim_radius + p.finger_reach) * a
            centre = bowl[:2] + side * p.rim_radius * a
            block, gap = -np.inf, np.inf
            for xy0, g, half, zs in (
                (finger, grid, p.finger_half, levels),
                (centre, palm_grid, PALM_HALF, palm_levels),
            ):
                b, d = path_clearance(boxes, xy0 + g[:, :1] * half[0] * a + g[:, 1:] * half[1] * perp, zs)
                block, gap = max(block, b), min(gap, d)
            # under an overhang, the hand on the side the bowl leaves towards (the arm away from it)
            away = self.escape is not None and float(side * a @ self.escape) <= 0.0
            keys.append((block > -np.inf, away, block, gap < p.min_gap, k))
        yaw, side = CANDIDATES[min(keys)[-1]]
        self.grasp_choice = {"yaw_deg": float(yaw), "side": float(side)}
        a3 = np.array([*closing_axes(yaw)[0], 0.0])
        return side * p.rim_radius * a3 + np.array([0.0, 0.0, p.grasp_height]), yawed(yaw)


class ItemPlacer(ObjectExpert):
    """Any other item, by its footprint (ObjectExpert's grasp), onto or into any target."""

    name = "gazereg.envs.libero.expert_goal.ItemPlacer"
    exact_corridor = False  # heights from `corridor_top` (set when time is short), else PickPlaceExpert's

    def _corridor_top(self, boxes: Any, a: np.ndarray, b: np.ndarray) -> float:
        if self.exact_corridor:
            return corridor_top(boxes, a, b, self.p.corridor)
        return super()._corridor_top(boxes, a, b)

    def reset(self, env: Any, noise_seed: Any = 0) -> None:
        self.relation = env.roles.relation
        super().reset(env, noise_seed)

    def _plan(self, env: Any, pts: dict[str, np.ndarray], boxes: Any) -> Plan:
        plan = super()._plan(env, pts, boxes)
        shape = ItemShape.of(env.scene_facts.geom_boxes(env.roles.obj))
        surface = support_top(env, env.roles.goal, pts["goal"][:2])
        origin_z = float(pts["obj"][2])
        plan.place_dz = surface + self.p.release_gap + (origin_z - shape.bottom) - float(pts["goal"][2])
        return plan
