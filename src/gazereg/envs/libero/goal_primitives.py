"""The motion primitives of LIBERO-Goal's expert (`gazereg.envs.libero.expert_goal.GoalExpert` mixes them in):
pull a drawer, turn a knob, push an object, each planned as a list of `Waypoint`s.

Primitives. "pull", "turn" and "push" are lists of `Waypoint`s run in order: each a hand target (the point
between the finger pads, world, metres), a gripper orientation (3, 3) and command, a speed (the position
action's largest component, of 1) and an end (the target within `tolerance`, `via_tolerance` for a point passed
on the way, and the orientation within `rot_tolerance` radians; a number of steps for the gripper to close or
open; a joint reaching its goal); every waypoint ends after `max_phase_steps` at the latest. The control is
`PickPlaceExpert`'s (OSC_POSE delta actions, `gain * error / output_max`, optional Gaussian action noise `noise`
from the `reset` noise seed, one stream for the whole episode).

    pull  the handle: the drawer's collision box farthest along the opening direction (the slide joint's axis,
          signed towards LIBERO's open range); the gripper points against the opening direction, the fingers
          closing across the bar (perpendicular to it and to the pull). Up to a safe height, over a point
          `pull_standoff` in front of the handle turning the wrist on the way, down to the handle's height, in
          (the pads `pull_out` in front of the bar's centre), close, pull by the joint's distance to the middle
          of its open range (+ `pull_extra`) until LIBERO calls it open, open, back off by `back_off`, up (and,
          before placing, the wrist back to pointing down).
    turn  the knob: the collision boxes of the knob joint's body standing `ridge_min` above its lowest top (the
          ridge); the fingers close across the ridge's narrow side, the pads `knob_pad_below` under its top,
          over the joint's axis. Above, down, close, turn the wrist about the vertical by the angle from the
          joint's position to `turn_past` beyond the lower end of LIBERO's turn-on range (sign from the
          joint's axis), at most `turn_speed` of the controller's rotation per step, open, up.
    push  a dish (its top `dish_depth` above its centre's floor: the plate): the open fingers, across the push
          direction, down at its centre, the fingertips `dish_height` above its floor (below: pressing on it);
          anything else: the fingertips `push_height` above the table, `push_gap` behind its footprint. Then the
          hand keeps its offset to the object, `push_lead` further towards the region's centre (a closed loop
          on the object's position: a hand that slips waits for it), at `push_speed`, until the object's origin
          is within `tolerance` of the centre or `push_steps` have passed.

"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from gazereg.envs.libero.expert import (
    DOWN_ALONG_Y,
    GRIP_CLOSE,
    GRIP_OPEN,
    axis_angle_of,
    yawed,
)
from gazereg.envs.libero.expert_object import YAWS, ItemShape
from gazereg.envs.libero.goal_scene import (
    Joint,
    body_boxes,
    corridor_top,
    drawer_joints,
    frame,
    rot_z,
    support_top,
)
from gazereg.envs.libero.scene import Boxes


@dataclass
class Waypoint:
    """One step of a primitive: the hand (between the finger pads) towards `target(pts)` (3,) world metres, the
    gripper towards `rot` (3, 3) with command `grip`; position action at most `speed`, rotation at most
    `rot_speed`. Ends when reached (position and orientation), after `steps` steps if set, or when `done()`."""

    name: str
    target: Callable[[dict[str, np.ndarray]], np.ndarray]
    rot: np.ndarray
    grip: float
    speed: float = 1.0
    rot_speed: float = 1.0
    steps: int | None = None
    done: Callable[[], bool] | None = None
    tolerance: float | None = None  # reached within this (metres); None: the expert's `tolerance`


class GoalPrimitives:
    """The pull, turn and push plans of `GoalExpert` (its `params`, a `GoalParams`, and its waypoint state are
    the expert's); each `_plan_*` sets the waypoints the expert then runs."""

    def _travel_z(self, a: np.ndarray, b: np.ndarray, hang: float) -> float:
        """The height (pad centre) for moving sideways from a to b: the obstacles near the path, cleared."""
        boxes = self._env.scene_facts.obstacles()
        return corridor_top(boxes, a, b, self.p.corridor) + self.p.clearance + hang

    def _drawer_slide(self, env: Any, region: str, ranges: str) -> tuple[Joint, float, float, np.ndarray]:
        """`region`'s drawer: its slide joint, the joint's value now and its goal (the middle of the cabinet's
        articulation `ranges`: "default_open_ranges" or "default_close_ranges"), and the unit direction (3,),
        world, the drawer moves in to reach the goal (zero when it is there)."""
        e = env.unwrapped_libero.env
        owner = env.scene_facts.owner(region)
        goal_range = e.get_object(owner).object_properties["articulation"][ranges]
        joint = Joint.named(env, drawer_joints(env, region)[0])
        q0, q_goal = joint.value(env), float(np.mean(goal_range))
        u = joint.axis * np.sign(q_goal - q0)
        return joint, q0, q_goal, u / max(float(np.linalg.norm(u)), 1e-9)

    def _plan_pull(self, env: Any, region: str) -> None:
        """Waypoints that pull `region`'s drawer open (see the module docstring, "pull")."""
        joint, q0, q_goal, u = self._drawer_slide(env, region, "default_open_ranges")
        travel = abs(q_goal - q0) + self.p.pull_extra
        boxes = body_boxes(env, joint.body)
        k = int(np.argmax(boxes.centre @ u))
        handle0 = boxes.centre[k].copy()
        long_axis = boxes.rot[k][:, int(np.argmax(boxes.half[k]))]
        closing = np.cross(long_axis, u)
        closing /= np.linalg.norm(closing)
        # of the two closing directions, the one the wrist reaches with the least turn from pointing down
        rots = [frame(-u, s * closing) for s in (1.0, -1.0)]
        R = min(rots, key=lambda r: np.linalg.norm(axis_angle_of(r @ DOWN_ALONG_Y.T)))
        p = self.p
        hand0 = env.key_points()["hand"]
        start = handle0 + u * p.pull_standoff
        high = max(self._travel_z(hand0, start, p.tip_depth), float(start[2]) + p.hover)
        grip_at = handle0 + u * p.pull_out
        body = joint.body

        def handle_now() -> np.ndarray:
            return boxes.centre[k] + env.physics_data.xpos[body] - xpos0

        xpos0 = env.physics_data.xpos[body].copy()
        self._parts["handle"] = lambda: (handle_now(), self._touches(env, body))

        def opened() -> bool:
            return self._is_open(env, region)

        self.grasp_choice = {"handle_axis": [float(x) for x in closing]}
        via = p.via_tolerance
        up = np.array([0, 0, p.retreat_height])

        def rise(pts: dict[str, np.ndarray]) -> np.ndarray:
            return np.array([*pts["hand"][:2], high])

        wps = [
            Waypoint("rise", rise, DOWN_ALONG_Y, GRIP_OPEN, tolerance=via),
            Waypoint("over", lambda pts: np.array([*start[:2], high]), R, GRIP_OPEN, 1.0, 0.5, tolerance=via),
            Waypoint("down", lambda pts: start, R, GRIP_OPEN),
            Waypoint("in", lambda pts: grip_at, R, GRIP_OPEN, speed=0.6),
            Waypoint("close", lambda pts: grip_at, R, GRIP_CLOSE, steps=p.close_steps),
            Waypoint("pull", lambda pts: grip_at + u * travel, R, GRIP_CLOSE, p.pull_speed, done=opened),
            Waypoint("release", lambda pts: self._held(pts), R, GRIP_OPEN, steps=p.open_steps),
            Waypoint("back_off", lambda pts: self._held(pts, u * p.back_off), R, GRIP_OPEN),
        ]
        wps.append(Waypoint("up", lambda pts: self._held(pts, up), R, GRIP_OPEN, tolerance=via))
        if self.kind == "open_place":  # the wrist back to pointing down, clear of the drawer, for the placing
            wps.append(Waypoint("unturn", self._held, DOWN_ALONG_Y, GRIP_OPEN, tolerance=via))
        self._waypoints = wps

    def _plan_turn(self, env: Any, fixture: str) -> None:
        """Waypoints that turn `fixture`'s knob on (see the module docstring, "turn")."""
        e = env.unwrapped_libero.env
        obj = e.get_object(fixture)
        ranges = obj.object_properties["articulation"]["default_turnon_ranges"]
        joint = Joint.named(env, list(obj.joints)[0])
        q0, q_goal = joint.value(env), float(min(ranges)) + self.p.turn_past
        p = self.p
        boxes = body_boxes(env, joint.body)
        tops = boxes.top()
        ridge = tops > tops.min() + p.ridge_min
        rb = Boxes(boxes.centre[ridge], boxes.rot[ridge], boxes.half[ridge])
        shape = ItemShape.of(rb)
        yaw = min(YAWS, key=lambda y: (round(shape.footprint(y)[0] / 0.005), abs(y)))
        R0 = yawed(yaw)
        sign = float(np.sign(joint.axis[2])) or 1.0
        R1 = rot_z(sign * (q_goal - q0)) @ R0
        low_top = float(tops[~ridge].max()) if (~ridge).any() else float(tops.min())
        pad_z = max(shape.top - p.knob_pad_below, low_top + p.tip_depth + 0.003)
        grasp = np.array([joint.anchor[0], joint.anchor[1], pad_z])
        hand0 = env.key_points()["hand"]
        high = max(self._travel_z(hand0, grasp, p.tip_depth), pad_z + p.hover)
        self._parts["knob"] = lambda: (grasp.copy(), self._touches(env, joint.body))
        self.grasp_choice = {"yaw_deg": float(yaw)}

        def turned() -> bool:  # the knob within `turn_slack` of its goal
            return sign * joint.value(env) >= sign * q_goal - p.turn_slack

        self._waypoints = [
            Waypoint("rise", lambda pts: np.array([*pts["hand"][:2], high]), R0, GRIP_OPEN),
            Waypoint("above", lambda pts: np.array([*grasp[:2], high]), R0, GRIP_OPEN),
            Waypoint("descend", lambda pts: grasp, R0, GRIP_OPEN, speed=0.5),
            Waypoint("close", lambda pts: grasp, R0, GRIP_CLOSE, steps=p.close_steps),
            Waypoint("turn", lambda pts: grasp, R1, GRIP_CLOSE, rot_speed=p.turn_speed, done=turned),
            Waypoint("release", lambda pts: self._held(pts), R1, GRIP_OPEN, steps=p.open_steps),
            Waypoint("up", lambda pts: self._held(pts, np.array([0, 0, p.retreat_height])), R1, GRIP_OPEN),
        ]

    def _plan_push(self, env: Any) -> None:
        """Waypoints that push the object onto the region's centre (see the module docstring, "push")."""
        p = self.p
        pts0 = env.key_points()
        obj0, goal = pts0["obj"], pts0["goal"]
        d = goal[:2] - obj0[:2]
        u = np.append(d / max(float(np.linalg.norm(d)), 1e-9), 0.0)
        shape = ItemShape.of(env.scene_facts.geom_boxes(env.roles.obj))
        rel = shape.corners[:, :2] - obj0[:2]
        radius = float(np.max(-(rel @ u[:2])))  # the footprint's extent behind the origin
        floor = support_top(env, env.roles.obj, obj0[:2])
        dish = shape.top - floor > p.dish_depth  # a plate: the fingers go in and drag it by its rim
        yaw = float(np.degrees(np.arctan2(u[1], u[0])))  # closing axis across the push: along (-u_y, u_x)
        yaw = (yaw + 90.0) % 180.0 - 90.0
        R = yawed(yaw)
        table = float(shape.bottom)
        if dish:
            pad_z = floor + p.dish_height + p.finger_tip
            start = np.array([*obj0[:2], pad_z])
        else:
            pad_z = table + p.push_height + p.tip_depth
            start = np.array([*(obj0[:2] - u[:2] * (radius + p.push_gap)), pad_z])
        high = max(self._travel_z(pts0["hand"], start, p.tip_depth), pad_z + p.hover)
        self.grasp_choice = {"yaw_deg": yaw, "inside": float(dish)}

        def push_target(pts: dict[str, np.ndarray]) -> np.ndarray:
            # the hand's offset to the object when the push began, `push_lead` further towards the goal: a
            # hand that slips over the object waits for it instead of running ahead
            if self._hold is None:
                self._hold = pts["hand"] - pts["obj"]
            d = pts["goal"][:2] - pts["obj"][:2]
            dist = float(np.linalg.norm(d))
            xy = pts["obj"][:2] + self._hold[:2] + d / max(dist, 1e-9) * min(p.push_lead, dist)
            return np.array([*xy, pad_z])

        def arrived() -> bool:
            pts = env.key_points()
            return bool(np.linalg.norm(pts["obj"][:2] - pts["goal"][:2]) < p.tolerance)

        self._waypoints = [
            Waypoint("rise", lambda pts: np.array([*pts["hand"][:2], high]), R, GRIP_OPEN),
            Waypoint("above", lambda pts: np.array([*start[:2], high]), R, GRIP_OPEN),
            Waypoint("descend", lambda pts: start, R, GRIP_OPEN, speed=0.6),
            Waypoint("push", push_target, R, GRIP_OPEN, speed=p.push_speed, done=arrived, steps=p.push_steps),
            Waypoint("up", lambda pts: self._held(pts, np.array([0, 0, p.retreat_height])), R, GRIP_OPEN),
        ]

    # ----- facts for the gaze ---------------------------------------------------------------------------
