"""A scripted bimanual expert for Gym-Aloha: end-effector waypoints per arm, turned into joint commands by a
damped least-squares inverse kinematics over each arm's Jacobian.

    expert = AlohaExpert()
    expert.reset(env, seed)        # plan the waypoints of this setup (object poses read from the physics)
    action = expert(env)           # (14,): gym-aloha's joint-position action

Each arm follows a piecewise-linear path of grasp-point poses (`Waypoint`: step, position in metres, the
gripper's pointing direction as a horizontal heading and a downward pitch, its opening 0..1). Every step the
commanded pose is interpolated (headings the shorter way round) and `ArmIK.solve` moves the commanded joints
(warm-started from the last command) until the grasp point is within 1 mm of it, with a weak pull of the two
wrist rolls towards 0 that keeps the wrist out of its flipped solutions. The IK runs on a scratch `MjData` of
the env's model, so it never disturbs the simulation; the 6 joints it returns are the action, sent to
gym-aloha's position servos. Where the grasp decides where an object ends up, the arm steers on the measured
object poses instead (integral control of the commanded grasp point, `_steer`).

Transfer cube: the right arm takes the cube from above (pitched 60 degrees down, fingers closing across its
heading) and carries it to the meeting point `AlohaTask.meet`; the left arm comes in level from the left with
its fingers closing vertically, steering on the cube's measured centre, closes on it; the right arm lets go
and backs away.
Insertion: the right arm takes the peg by its right end, the left arm the socket by its left end, both lift
them to the meeting point, level, the peg 4 cm right of the socket's mouth; then the right arm pushes the peg
along the socket's axis, steering by the measured peg and socket positions (the grasp is never exact) until
the peg touches the pin; meanwhile the right wrist turns until the peg's axis is parallel to the socket's.
The measured success (python -m gazereg.envs.aloha.measure): docs/aloha.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from gazereg.envs.aloha.env import ARM_JOINTS, ARMS, GRASP_POINT

OPEN, CLOSED = 1.0, 0.0
# Heights (world z, metres) of the objects' centres at rest on the table (they are placed 5 cm up and fall) and of
# the grasp point when the fingers close on them.
CUBE_GRASP_Z = 0.035
PEG_REST_Z, PEG_GRASP_Z = 0.01, 0.02
SOCKET_REST_Z, SOCKET_GRASP_Z = 0.02, 0.03
HANDOVER_FROM = 210
MAX_STEER = 0.005
STEER_GAIN = 0.3
ROLL_WEIGHT = 0.02
"""weight of the IK's pull of the two wrist rolls towards 0 (metres of grasp-point error per radian)"""
"""the steering (hand-over, insertion) moves a commanded grasp point at most this far per step (m), by this share
of the measured error"""


@dataclass(frozen=True)
class Waypoint:
    """Where one arm's grasp point is at step `t`: position (3,) metres (world), pointing heading `yaw` (radians,
    0 = world +x) and downward `pitch` (radians, 0 = level), fingers closing across the heading unless `roll`
    (radians about the pointing axis; pi/2: closing vertically), gripper opening `grip` (0 closed, 1 open)."""

    t: int
    pos: tuple[float, float, float]
    yaw: float
    pitch: float
    grip: float
    roll: float = 0.0


def gripper_rotation(yaw: float, pitch: float, roll: float = 0.0) -> np.ndarray:
    """The gripper frame (3, 3) (columns: pointing x, finger-closing y, z) for heading `yaw`, downward `pitch`
    and `roll` about the pointing axis, radians."""
    h = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    x = np.array([np.cos(pitch) * h[0], np.cos(pitch) * h[1], -np.sin(pitch)])
    y0 = np.array([-h[1], h[0], 0.0])
    z0 = np.cross(x, y0)
    y = np.cos(roll) * y0 + np.sin(roll) * z0
    return np.stack([x, y, np.cross(x, y)], axis=1)


class ArmIK:
    """Damped least-squares IK of one arm's grasp point (position and orientation) over its 6 joints."""

    def __init__(self, model: Any, arm: str, damping: float = 0.05, rot_weight: float = 0.3):
        import mujoco

        self._mj = mujoco
        self.m = model
        self.d = mujoco.MjData(model)
        joints = [model.joint(f"vx300s_{arm}/{j}") for j in ARM_JOINTS]
        self.qadr = np.array([int(j.qposadr[0]) for j in joints])
        self.dadr = np.array([int(j.dofadr[0]) for j in joints])
        self.lo = np.array([model.jnt_range[j.id][0] for j in joints])
        self.hi = np.array([model.jnt_range[j.id][1] for j in joints])
        # Two extra rows pull forearm_roll and wrist_rotate towards 0 (weight ROLL_WEIGHT): near the wrist's
        # singularity (wrist_angle ~ 0, the two roll axes aligned) the solver otherwise winds both towards +-pi,
        # the same poses with the wrist flipped, where the joints' limits leave it unable to follow a target.
        self.rolls = np.array([ARM_JOINTS.index("forearm_roll"), ARM_JOINTS.index("wrist_rotate")])
        self.body = model.body(f"vx300s_{arm}/gripper_link").id
        self.damping, self.w = damping, rot_weight
        self._jp = np.zeros((3, model.nv))
        self._jr = np.zeros((3, model.nv))

    def pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Grasp point (3,) and gripper frame (3, 3) at joints `q` (6,)."""
        self.d.qpos[self.qadr] = q
        self._mj.mj_kinematics(self.m, self.d)
        R = self.d.xmat[self.body].reshape(3, 3)
        return self.d.xpos[self.body] + R @ GRASP_POINT, R.copy()

    def solve(
        self, q0: np.ndarray, pos: np.ndarray, R: np.ndarray, iters: int = 40, tol: float = 1e-3
    ) -> np.ndarray:
        """Joints (6,) that put the grasp point at `pos` (3,) with frame `R` (3, 3), starting from `q0`."""
        q = np.array(q0, dtype=np.float64)
        lam2 = self.damping**2
        for _ in range(iters):
            p, Rc = self.pose(q)
            ep = pos - p
            er = 0.5 * sum(np.cross(Rc[:, i], R[:, i]) for i in range(3))
            if np.linalg.norm(ep) < tol and np.linalg.norm(er) < 1e-2:
                break
            self._mj.mj_comPos(self.m, self.d)
            self._mj.mj_jac(self.m, self.d, self._jp, self._jr, p, self.body)
            S = np.zeros((2, 6))
            S[[0, 1], self.rolls] = ROLL_WEIGHT
            J = np.vstack([self._jp[:, self.dadr], self.w * self._jr[:, self.dadr], S])
            e = np.concatenate([ep, self.w * er, -ROLL_WEIGHT * q[self.rolls]])
            dq = J.T @ np.linalg.solve(J @ J.T + lam2 * np.eye(8), e)
            q = np.clip(q + np.clip(dq, -0.2, 0.2), self.lo, self.hi)
        return q


def _interp(path: list[Waypoint], t: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(position (3,), frame (3, 3), grip) of `path` at step `t` (held after the last waypoint)."""
    if t <= path[0].t:
        w = path[0]
        return np.asarray(w.pos), gripper_rotation(w.yaw, w.pitch, w.roll), w.grip
    for a, b in zip(path, path[1:], strict=False):
        if t <= b.t:
            s = (t - a.t) / max(b.t - a.t, 1)
            s = s * s * (3 - 2 * s)  # smoothstep: start and stop without a jerk
            pos = (1 - s) * np.asarray(a.pos) + s * np.asarray(b.pos)
            # the shorter way round: a heading of -173 degrees goes to 180 by 7 degrees, not by 353
            dyaw = (b.yaw - a.yaw + np.pi) % (2 * np.pi) - np.pi
            ang = (a.yaw + s * dyaw, (1 - s) * a.pitch + s * b.pitch, (1 - s) * a.roll + s * b.roll)
            return pos, gripper_rotation(*ang), (1 - s) * a.grip + s * b.grip
    w = path[-1]
    return np.asarray(w.pos), gripper_rotation(w.yaw, w.pitch, w.roll), w.grip


class AlohaExpert:
    """The scripted bimanual expert of both Gym-Aloha tasks (see the module docstring)."""

    name = "aloha_waypoints_dls_ik"

    def __init__(self, noise: float = 0.0):
        self.noise = float(noise)
        self.paths: dict[str, list[Waypoint]] = {}

    def reset(self, env: Any, seed: list[int] | int = 0) -> None:
        """Plan this setup's waypoints from the objects' poses (env just reset)."""
        self.rng = np.random.default_rng(seed)
        self.t = 0
        self.env = env
        self.steering: set[str] = set()  # the arms steering on measured poses (from then on, to the end)
        self.ik = {a: ArmIK(env.physics_model, a) for a in ARMS}
        q = env.physics_data.qpos
        self.q = {a: np.array(q[self.ik[a].qadr]) for a in ARMS}
        start = {a: env.grasp_point(a) for a in ARMS}
        if env.spec_task.gym_task == "transfer_cube":
            self.paths = self._plan_transfer(env, start)
        else:
            self.paths = self._plan_insertion(env, start)

    # ----- plans ------------------------------------------------------------------------------------------
    @staticmethod
    def _heading(base_x: float, p: np.ndarray) -> float:
        return float(np.arctan2(p[1] - 0.5, p[0] - base_x))

    def _plan_transfer(self, env: Any, start: dict[str, np.ndarray]) -> dict[str, list[Waypoint]]:
        cube, _ = env.object_pose(0)
        meet = np.asarray(env.spec_task.meet)
        yaw_r = self._heading(0.469, cube)
        pitch = np.radians(60)
        grasp = np.array([cube[0], cube[1], CUBE_GRASP_Z])
        above = grasp + [0.0, 0.0, 0.10]
        right = [
            Waypoint(0, tuple(start["right"]), np.pi, np.radians(-6), OPEN),
            Waypoint(70, tuple(above), yaw_r, pitch, OPEN),
            Waypoint(110, tuple(grasp), yaw_r, pitch, OPEN),
            Waypoint(130, tuple(grasp), yaw_r, pitch, CLOSED),
            Waypoint(210, tuple(meet), np.pi, np.radians(45), CLOSED),
            Waypoint(300, tuple(meet), np.pi, np.radians(45), CLOSED),
            Waypoint(320, tuple(meet), np.pi, np.radians(45), OPEN),
            Waypoint(370, tuple(meet + [0.12, 0.0, 0.05]), np.pi, np.radians(45), OPEN),
        ]
        left = [
            Waypoint(0, tuple(start["left"]), 0.0, np.radians(-6), OPEN),
            Waypoint(130, tuple(start["left"]), 0.0, 0.0, OPEN, np.pi / 2),
            Waypoint(210, tuple(meet + [-0.12, 0.0, 0.0]), 0.0, 0.0, OPEN, np.pi / 2),
            Waypoint(260, tuple(meet + [-0.025, 0.0, 0.0]), 0.0, 0.0, OPEN, np.pi / 2),
            Waypoint(290, tuple(meet + [-0.025, 0.0, 0.0]), 0.0, 0.0, CLOSED, np.pi / 2),
        ]
        return {"left": left, "right": right}

    def _plan_insertion(self, env: Any, start: dict[str, np.ndarray]) -> dict[str, list[Waypoint]]:
        peg, _ = env.object_pose(0)
        socket, _ = env.object_pose(1)
        meet = np.asarray(env.spec_task.meet)
        pitch = np.radians(70)
        peg_grip = np.array([peg[0] + 0.03, peg[1], PEG_GRASP_Z])
        sock_grip = np.array([socket[0] - 0.03, socket[1], SOCKET_GRASP_Z])
        hold_pitch = pitch  # the pitch they were taken at: the objects stay level
        # carried: the socket's centre at `meet`, the peg level 4 cm right of the socket's mouth
        self.sock_off = sock_grip - [socket[0], socket[1], SOCKET_REST_Z]
        self.peg_off = peg_grip - [peg[0], peg[1], PEG_REST_Z]
        sock_at = meet + self.sock_off
        peg_at = meet + [0.12 + 0.04, 0.0, 0.0] + self.peg_off
        right = [
            Waypoint(0, tuple(start["right"]), np.pi, np.radians(-6), OPEN),
            Waypoint(70, tuple(peg_grip + [0, 0, 0.10]), np.pi, pitch, OPEN),
            Waypoint(110, tuple(peg_grip), np.pi, pitch, OPEN),
            Waypoint(130, tuple(peg_grip), np.pi, pitch, CLOSED),
            Waypoint(160, tuple(peg_grip + [0, 0, 0.10]), np.pi, pitch, CLOSED),
            Waypoint(230, tuple(peg_at), np.pi, hold_pitch, CLOSED),
        ]
        left = [
            Waypoint(0, tuple(start["left"]), 0.0, np.radians(-6), OPEN),
            Waypoint(70, tuple(sock_grip + [0, 0, 0.10]), 0.0, pitch, OPEN),
            Waypoint(110, tuple(sock_grip), 0.0, pitch, OPEN),
            Waypoint(130, tuple(sock_grip), 0.0, pitch, CLOSED),
            Waypoint(160, tuple(sock_grip + [0, 0, 0.10]), 0.0, pitch, CLOSED),
            Waypoint(230, tuple(sock_at), 0.0, hold_pitch, CLOSED),
        ]
        self.insert_from = 250
        self.insert_steps = 90
        self.peg_pitch, self.peg_yaw = float(hold_pitch), float(np.pi)
        return {"left": left, "right": right}

    # ----- acting -----------------------------------------------------------------------------------------
    def _insertion_target(self, t: int) -> np.ndarray | None:
        """From `insert_from` on: the right grasp point that moves the peg's centre from 16 to 9 cm right of
        the socket's centre along the socket's axis, corrected by the peg's measured offset in the grip."""
        if self.env.spec_task.gym_task != "insertion" or t < self.insert_from:
            return None
        if "right" not in self.steering and not self.env.contact_state()[0]:
            return None  # the peg is not in the right hand: nothing to steer (once started, a flicker of
            # the fingers' contact must not send the arm back to its waypoints)
        self.steering.add("right")
        s = min(1.0, (t - self.insert_from) / self.insert_steps)
        socket, Rs = self.env.object_pose(1)
        peg, _ = self.env.object_pose(0)
        axis = Rs[:, 0] if Rs[0, 0] > 0 else -Rs[:, 0]
        want_peg = socket + axis * ((1 - s) * 0.16 + s * 0.09)
        return self._steer("right", want_peg - peg)

    def _level_peg(self) -> np.ndarray:
        """The right gripper's frame during the insertion: its pitch and heading turned, a fifth of the error per
        step, until the peg's axis is parallel to the socket's (the peg turns in the grip when it is taken)."""
        _, Rp = self.env.object_pose(0)
        _, Rs = self.env.object_pose(1)
        peg = Rp[:, 0] if Rp[0, 0] > 0 else -Rp[:, 0]
        sock = Rs[:, 0] if Rs[0, 0] > 0 else -Rs[:, 0]
        tilt = np.arcsin(np.clip(peg[2], -1, 1)) - np.arcsin(np.clip(sock[2], -1, 1))
        turn = np.arctan2(peg[1], peg[0]) - np.arctan2(sock[1], sock[0])
        self.peg_pitch -= 0.2 * tilt
        self.peg_yaw -= 0.2 * turn
        return gripper_rotation(self.peg_yaw, self.peg_pitch)

    def _handover_target(self, t: int) -> np.ndarray | None:
        """Transfer, from step 210 on while the right hand holds the cube: the left grasp point goes from 12 cm
        to 1.5 cm left of the cube's measured centre (where the cube hangs in the right hand varies)."""
        if self.env.spec_task.gym_task != "transfer_cube" or t < HANDOVER_FROM:
            return None
        if "left" not in self.steering and not self.env.contact_state()[0]:
            return None
        self.steering.add("left")
        s = min(1.0, (t - HANDOVER_FROM) / 50)
        s = s * s * (3 - 2 * s)
        cube, _ = self.env.object_pose(0)
        target = cube + [(1 - s) * -0.12 + s * -0.015, 0.0, 0.0]
        return self._steer("left", target - self.env.grasp_point("left"))

    def _steer(self, arm: str, error: np.ndarray) -> np.ndarray:
        """The commanded grasp point moved by a share (`STEER_GAIN`, at most `MAX_STEER` metres) of a measured
        position `error` (3,): integral control, so the servos' lag and sag under load leave no steady offset."""
        here, _ = self.ik[arm].pose(self.q[arm])
        step = STEER_GAIN * np.asarray(error)
        n = np.linalg.norm(step)
        return here + (step * min(1.0, MAX_STEER / n) if n > 0 else step)

    def __call__(self, env: Any) -> np.ndarray:
        action = np.zeros(14)
        for i, a in enumerate(ARMS):
            pos, R, grip = _interp(self.paths[a], self.t)
            if a == "right" and (target := self._insertion_target(self.t)) is not None:
                pos, R = target, self._level_peg()
            if a == "left" and (target := self._handover_target(self.t)) is not None:
                pos = target
            self.q[a] = self.ik[a].solve(self.q[a], pos, R)
            action[7 * i : 7 * i + 6] = self.q[a]
            action[7 * i + 6] = grip
        if self.noise > 0:
            action[[0, 1, 2, 3, 4, 5, 7, 8, 9, 10, 11, 12]] += self.rng.normal(0, self.noise, 12)
        self.t += 1
        return action.astype(np.float32)
