"""LIBERO-10's new motion primitives (`gazereg.envs.libero.expert_10`, whose docstring describes them): "shut" (a
drawer pushed closed) and "swing" (a hinged door moved along its arc about the hinge), as `Waypoint` lists, beside
LIBERO-Goal's pull, turn and push (`gazereg.envs.libero.goal_primitives`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from gazereg.envs.libero.expert import (
    DOWN_ALONG_Y,
    GRIP_CLOSE,
    axis_angle_of,
)
from gazereg.envs.libero.goal_primitives import GoalPrimitives, Waypoint
from gazereg.envs.libero.goal_scene import (
    Joint,
    body_boxes,
    frame,
    rot_z,
)


class LongPrimitives(GoalPrimitives):
    """The shut and swing primitives, mixed into `LongExpert` (its params: `LongParams`)."""

    def _plan_shut(self, env: Any, region: str) -> None:
        """Waypoints that push `region`'s drawer shut (see the module docstring, "shut")."""
        joint, q0, q_goal, towards = self._drawer_slide(env, region, "default_close_ranges")
        u = -towards  # the opening direction (out of the cabinet)
        p = self.p
        travel = abs(q_goal - q0) + p.shut_extra
        boxes = body_boxes(env, joint.body)
        k = int(np.argmax(boxes.centre @ u))
        handle0 = boxes.centre[k].copy()
        front = float(np.max(boxes.corners().reshape(-1, 8, 3)[k] @ u))  # the handle's front, along u
        body = joint.body
        xpos0 = env.physics_data.xpos[body].copy()
        self._parts["handle"] = lambda: (
            boxes.centre[k] + env.physics_data.xpos[body] - xpos0,
            self._touches(env, body),
        )
        # the closed fingers (pointing down, closing across the push) against the handle's front
        closing = np.cross(np.array([0.0, 0.0, 1.0]), u)[:2]
        closing3 = np.array([*closing, 0.0]) / max(float(np.linalg.norm(closing)), 1e-9)
        rots = [frame(np.array([0.0, 0.0, -1.0]), sgn * closing3) for sgn in (1.0, -1.0)]
        now = self._ori()  # of the two, the one the wrist reaches with the least turn from where it is
        R = min(rots, key=lambda r: np.linalg.norm(axis_angle_of(r @ now.T)))
        # then tilted `shut_tilt` about the closing axis, the fingertips leading into the cabinet: the forearm
        # stays back from the cabinet's front
        t = p.shut_tilt * float(np.sign(np.cross(R[:, 0], np.array([0.0, 0.0, -1.0])) @ -u) or 1.0)
        R_tilt = _rot_about(R[:, 0], t) @ R
        pad_z = float(handle0[2]) + p.finger_tip - p.shut_low
        along = handle0 + u * (front - float(handle0 @ u))  # the handle's front face, at its centre
        start = np.array([*(along + u * p.shut_standoff)[:2], pad_z])
        press = np.array([*(along + u * p.finger_half_width)[:2], pad_z])
        hand0 = env.key_points()["hand"]
        high = max(self._travel_z(hand0, start, p.tip_depth), pad_z + p.hover)

        def shut() -> bool:
            return bool(env.unwrapped_libero.env.object_states_dict[region].is_close())

        via = p.via_tolerance
        self._waypoints = [
            Waypoint("rise", lambda pts: np.array([*pts["hand"][:2], high]), R, GRIP_CLOSE, tolerance=via),
            Waypoint("over", lambda pts: np.array([*start[:2], high]), R, GRIP_CLOSE, tolerance=via),
            Waypoint("down", lambda pts: start, R, GRIP_CLOSE),
            Waypoint("tilt", lambda pts: start, R_tilt, GRIP_CLOSE, rot_speed=0.5),
            Waypoint(
                "push",
                lambda pts: press - u * travel,
                R_tilt,
                GRIP_CLOSE,
                p.shut_speed,
                steps=p.shut_steps,
                done=shut,
            ),
            Waypoint("back_off", lambda pts: self._held(pts, u * 0.06), R_tilt, GRIP_CLOSE, tolerance=via),
        ]

    def _plan_swing(self, env: Any, fixture: str) -> None:
        """Waypoints that swing `fixture`'s hinged door shut (see the module docstring, "swing")."""
        e = env.unwrapped_libero.env
        obj = e.get_object(fixture)
        ranges = obj.object_properties["articulation"]["default_close_ranges"]
        joint = Joint.named(env, list(obj.joints)[0])
        q0, q_goal = joint.value(env), float(np.mean(ranges))
        sign = float(np.sign(joint.axis[2])) or 1.0
        turn = sign * (q_goal - q0)  # the door's world yaw change to close it
        p = self.p
        door = body_boxes(env, joint.body)
        hinge = joint.anchor
        corners = door.corners()
        rel = corners[:, :2] - hinge[:2]
        far = rel[int(np.argmax(np.linalg.norm(rel, axis=1)))]
        width = float(np.linalg.norm(far))
        r_dir = far / max(width, 1e-9)
        # the face the door sweeps towards when closing: the side the rotation moves the door's points to
        t_dir = np.sign(turn) * np.array([-r_dir[1], r_dir[0]])
        thick = float(np.max(-(rel @ t_dir)))  # the door's extent behind (against the sweep)
        z = float(np.clip(hinge[2], door.centre[:, 2].min(), door.centre[:, 2].max()))
        r = p.swing_reach * width
        body = joint.body
        self._parts["door"] = lambda: (
            np.array([*(hinge[:2] + rot_z(sign * (joint.value(env) - q0))[:2, :2] @ (r_dir * r)), z]),
            self._touches(env, body),
        )
        start = np.array([*(hinge[:2] + r_dir * r - t_dir * (thick + p.swing_gap)), z])
        hand0 = env.key_points()["hand"]
        high = max(self._travel_z(hand0, start, p.tip_depth), z + p.hover)

        def swing_target(pts: dict[str, np.ndarray]) -> np.ndarray:
            ang = sign * (joint.value(env) - q0) + np.sign(turn) * p.swing_step
            ang = float(np.clip(ang, min(0.0, turn), max(0.0, turn)))
            v = rot_z(ang)[:2, :2] @ (r_dir * r - t_dir * (thick + p.swing_gap * 0.3))
            return np.array([*(hinge[:2] + v), z])

        def closed() -> bool:
            return bool(e.object_states_dict[fixture].is_close())

        via = p.via_tolerance
        R = DOWN_ALONG_Y
        self._waypoints = [
            Waypoint("rise", lambda pts: np.array([*pts["hand"][:2], high]), R, GRIP_CLOSE, tolerance=via),
            Waypoint("over", lambda pts: np.array([*start[:2], high]), R, GRIP_CLOSE, tolerance=via),
            Waypoint("down", lambda pts: start, R, GRIP_CLOSE),
            Waypoint("swing", swing_target, R, GRIP_CLOSE, p.swing_speed, done=closed, steps=150),
            Waypoint("up", lambda pts: self._held(pts, np.array([0, 0, p.retreat_height])), R, GRIP_CLOSE),
        ]


def _rot_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """The rotation (3, 3) by `angle` radians about the unit vector `axis` (Rodrigues)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)
