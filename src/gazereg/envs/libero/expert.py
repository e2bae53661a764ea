"""A scripted pick-and-place expert for LIBERO-Spatial, driven by the simulator's object poses.

    env = LiberoEnv("libero_spatial/4", cameras=())
    expert = SpatialExpert(noise=0.0)
    obs, info = env.reset(seed=2)
    expert.reset(env, noise_seed=[2, 0])
    action = expert(env)                    # float32 (7,) in [-1, 1], LIBERO's OSC_POSE action

Every LIBERO-Spatial task is `(On <a black bowl> plate_1)`: pick the bowl up by its rim and put it on the plate.
The expert is a phase machine over the privileged facts of `LiberoEnv` (`key_points`: the bowl's and the plate's
body positions, the point between the finger pads):

    above      the open gripper rises to a safe height if needed, then goes above the grasp point
    descend    down to the grasp point, the fingers straddling the rim's wall
    close      the gripper closes (`close_steps` steps, the arm holding still)
    lift       straight up to the carrying height
    carry      over the plate: the hand's target is the plate plus the bowl's current offset from the hand
    lower      down until the bowl is `release_gap` above the plate's origin
    open       the gripper opens (`open_steps` steps)
    retreat    straight up

Grasp. The grasp point is `rim_radius` from the bowl's centre along the fingers' closing axis, so that the
inner finger comes down inside the bowl and the outer one outside its wall. The gripper points down; its yaw
and the side of the bowl are chosen once per episode from CANDIDATES (yaws 0, 90, +-45, ... degrees, both
sides): the first whose outer finger's path down is free of the obstacle boxes (`SceneFacts.obstacles`: the
other objects' and the furniture's collision geoms) with `min_gap` to spare; this is what takes the bowl out of
the cabinet's drawer or from next to the cookie box. Heights: the empty hand moves sideways `clearance` above
the obstacles near its path (within `corridor`), the carried bowl likewise; the bowl is lifted by `min_lift`
at least. A phase ends when the hand is within `tolerance` of its target (or after `max_phase_steps`); a bowl
that slips `slip` down in the hand while carried sends the expert back to `above` (`retries` times), so a
rollout adapts to where the bowl actually is.

Success, measured with `benchmarks/bench_libero.py --expert-inits 20` (init states 0-19 of the 10 tasks, no
noise, 300 steps): 197/200, the misses in the drawer task (4); 96/100 over init states 0-9 in an earlier run
(robosuite's resets of one environment are not bit-exact, so which initial states miss varies between runs).
Episodes take 85-210 steps on average per task (longest 297: the bowl next to the cookie box).

Control. OSC_POSE delta actions: robosuite's OSC moves its goal by `action * output_max` (read from the
controller: 0.05 m and 0.5 rad per unit by default), so the position action is `gain * error / output_max` and
the orientation action `gain * axis_angle(R_target R^T) / output_max`, both clipped to [-1, 1]. Optional
Gaussian noise of std `noise` (action units) on the arm's six components, from a generator seeded by
`reset(noise_seed=...)`: a rollout is a function of (setup seed, noise seed).

Shared. The phase machine, the heights and the control are `PickPlaceExpert`'s (parameters `MotionParams`);
an expert adds how it holds its object and puts it down (`_plan` -> `Plan`: grasp offset and orientation, the
hand's height over the object, the release height): `SpatialExpert` here (the bowl's rim, `ExpertParams`),
`gazereg.envs.libero.expert_object.ObjectExpert` for LIBERO-Object (an item into the basket).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

PHASES = ("above", "descend", "close", "lift", "carry", "lower", "open", "retreat")
# Gripper pointing down, fingers closing along world y (the columns are the gripper's axes in the world), and
# the same turned by 90 degrees about the vertical (fingers closing along world x).
DOWN_ALONG_Y = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
# Grasp candidates in order of preference: (yaw of the gripper about the vertical from DOWN_ALONG_Y, degrees;
# side of the bowl along the closing axis). The fingers are symmetric, so yaws in (-90, 90] cover every axis.
CANDIDATES = tuple(
    (yaw, side) for yaw in (0, 90, 45, -45, 30, -30, 60, -60, 15, -15, 75, -75) for side in (1.0, -1.0)
)


def yawed(yaw_deg: float) -> np.ndarray:
    """DOWN_ALONG_Y turned by `yaw_deg` about the world's vertical (3, 3)."""
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ DOWN_ALONG_Y


GRIP_OPEN, GRIP_CLOSE = -1.0, 1.0


@dataclass(frozen=True)
class MotionParams:
    """What every pick-and-place expert here shares: heights, gains and timing (metres, steps)."""

    hover: float = 0.08  # above the grasp point before descending
    clearance: float = 0.05  # the fingertips' / the carried object's margin above every obstacle while moving
    release_gap: float = 0.015  # the carried object's bottom above where it is put down, when opening
    tolerance: float = 0.01  # a phase's target is reached within this distance
    gain: float = 1.0  # proportional gain (1: the OSC goal lands on the target when not clipped)
    close_steps: int = 12
    open_steps: int = 8
    max_phase_steps: int = 80
    retreat_height: float = 0.1
    slip: float = 0.04  # the object this much lower in the hand than when grasped: dropped, grasp again
    retries: int = 2  # grasps after the first
    tip_depth: float = 0.025  # the fingertips below the pad centre
    min_gap: float = 0.015  # a free finger path this close to an obstacle is taken only when no other is free
    corridor: float = 0.1  # obstacles this far (horizontally) from a sideways move set its height
    min_lift: float = 0.1  # the object is lifted at least this much before it is carried
    carry_speed: float = 0.6  # the position action's largest component while holding the object (of 1)
    descend_speed: float = 1.0  # and while descending onto it (1: as fast as the controller goes)


@dataclass(frozen=True)
class ExpertParams(MotionParams):
    """The spatial expert's: defaults fit LIBERO's akita black bowl and the Panda gripper."""

    rim_radius: float = 0.04  # bowl centre to the grasp point (its wall is at 0.047), horizontally
    grasp_height: float = 0.035  # pad centre above the bowl's origin (its bottom) when grasping
    finger_reach: float = (
        0.042  # the open outer finger's centre beyond the grasp point, along the closing axis
    )
    finger_half: tuple[float, float] = (0.02, 0.025)  # its footprint's half sizes (along, across), margin in


def axis_angle_of(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) -> axis-angle vector (3,) (angle in radians times the unit axis)."""
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    angle = float(np.arccos(cos))
    if angle < 1e-8:
        return np.zeros(3)
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    n = np.linalg.norm(axis)
    if n < 1e-8:  # angle close to pi: the axis from the symmetric part
        w, v = np.linalg.eigh((R + R.T) / 2.0)
        axis = v[:, int(np.argmax(w))]
        n = 1.0
    return axis / n * angle


def path_clearance(boxes: Any, xy: np.ndarray, levels: np.ndarray) -> tuple[float, float]:
    """A finger's path down, the points `xy` (k, 2) at each height of `levels` (world, metres), against the
    obstacle `boxes`: (the highest z at which a point is inside a box, -inf if none; the smallest distance of
    a point to a box, inf without boxes)."""
    if not len(boxes):
        return -np.inf, np.inf
    pts = np.array([[x, y, z] for z in levels for x, y in xy])  # (levels * k, 3)
    dist = boxes.distance(pts).min(axis=1)
    hit = dist <= 0.0
    return (float(pts[hit, 2].max()) if hit.any() else -np.inf), float(dist.min())


@dataclass
class Plan:
    """How one episode's object is held and put down (set by an expert's `_plan` at reset; metres).

    offset: the grasp point (the pad centre) from the object's origin (3,); rot: the gripper's orientation
    (3, 3); hang: the pad centre above the object's lowest point; hand_above: the pad centre above the object's
    origin when held, expected (the held value is measured at the lift and clipped to `hand_bounds`);
    place_dz: the object's origin above the goal point when the gripper opens, less hand_above's play."""

    offset: np.ndarray
    rot: np.ndarray
    hang: float
    hand_above: float
    hand_bounds: tuple[float, float]
    place_dz: float


class PickPlaceExpert:
    """The phase machine every LIBERO pick-and-place expert here shares (PHASES; see the module docstring).

    A subclass names the goal relation it handles (`relation`), its parameters and `_plan(env, pts, boxes)`:
    the grasp and the release height for the episode (a `Plan`)."""

    name = "gazereg.envs.libero.expert.PickPlaceExpert"
    relation = "on"
    params_type: type[MotionParams] = MotionParams

    def __init__(self, noise: float = 0.0, params: MotionParams | None = None):
        if not noise >= 0:
            raise ValueError(f"action noise must be >= 0, got {noise}")
        self.noise = float(noise)
        self.p: Any = params or self.params_type()
        self.rng = np.random.default_rng(0)
        self.phase = PHASES[0]
        self._phase_steps = 0
        self._hold: np.ndarray | None = None
        self._out_max = np.array([0.05, 0.05, 0.05, 0.5, 0.5, 0.5])
        self._ori: Any = None  # () -> the gripper's orientation (3, 3); set by reset
        self.grasp_choice: dict[str, float] = {}
        self.plan: Plan | None = None  # this episode's, from reset
        self._tries = 0

    # ----- episode --------------------------------------------------------------------------------------
    def reset(self, env: Any, noise_seed: Any = 0) -> None:
        """Start an episode of `env` (a LiberoEnv just reset): read the controller's scale, plan heights and
        the grasp from the scene."""
        roles = env.roles
        if roles.relation != self.relation or roles.obj is None or roles.goal is None:
            raise ValueError(
                f"{type(self).__name__} puts an object {self.relation!r} another; task {env.task!r} has "
                f"roles {roles}"
            )
        ctrl = env.unwrapped_libero.env.robots[0].controller
        if not getattr(ctrl, "use_delta", True):
            raise ValueError(f"{type(self).__name__} needs a delta OSC_POSE controller (LIBERO's default)")
        self._out_max = np.abs(np.asarray(ctrl.output_max, dtype=np.float64)[:6])
        self._ori = lambda: np.asarray(ctrl.ee_ori_mat, dtype=np.float64)
        boxes = env.scene_facts.obstacles()
        pts = env.key_points()
        plan = self._plan(env, pts, boxes)
        self.plan = plan
        self._grasp_offset, self._R = plan.offset, plan.rot
        grasp = pts["obj"] + self._grasp_offset
        # Sideways moves clear the obstacles near their path: the empty hand's fingertips, the carried object.
        self._travel_z = self._corridor_top(boxes, pts["hand"], grasp) + self.p.clearance + self.p.tip_depth
        self._carry_z = max(
            self._corridor_top(boxes, grasp, pts["goal"]) + self.p.clearance + plan.hang,
            grasp[2] + self.p.min_lift,
        )
        self.rng = np.random.default_rng(noise_seed)
        self.phase = PHASES[0]
        self._phase_steps = 0
        self._hold = None
        self._offset_z = plan.hand_above
        self._tries = 0

    @property
    def regrasps(self) -> int:
        """How often this episode's object was found dropped and the grasp started over (at most `retries`)."""
        return self._tries

    def _plan(self, env: Any, pts: dict[str, np.ndarray], boxes: Any) -> Plan:
        raise NotImplementedError

    def _corridor_top(self, boxes: Any, a: np.ndarray, b: np.ndarray) -> float:
        """The highest top (z, metres) of the boxes within `corridor` (horizontally) of the segment a -> b."""
        if not len(boxes):
            return float(max(a[2], b[2]))
        c = boxes.centre[:, :2]
        ab = b[:2] - a[:2]
        u = np.clip(((c - a[:2]) @ ab) / max(float(ab @ ab), 1e-9), 0.0, 1.0)
        dist = np.linalg.norm(c - (a[:2] + u[:, None] * ab), axis=1)
        radius = np.linalg.norm(np.einsum("nij,nj->ni", np.abs(boxes.rot[:, :2, :]), boxes.half), axis=1)
        near = dist - radius < self.p.corridor
        return float(boxes.top()[near].max()) if near.any() else float(max(a[2], b[2]))

    # ----- control --------------------------------------------------------------------------------------
    def _arm(self, hand: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Position and orientation actions (6,) towards `target` (world, metres) and the grasp orientation."""
        pos = self.p.gain * (target - hand) / self._out_max[:3]
        rot = axis_angle_of(self._R @ self._ori().T)
        ori = self.p.gain * rot / self._out_max[3:]
        return np.clip(np.concatenate([pos, ori]), -1.0, 1.0)

    def _target(self, pts: dict[str, np.ndarray]) -> tuple[np.ndarray, float]:
        """The current phase's hand target (3,) and gripper command."""
        p, bowl, plate, hand = self.p, pts["obj"], pts["goal"], pts["hand"]
        grasp = bowl + self._grasp_offset
        over_plate = plate[:2] + (hand[:2] - bowl[:2])  # the object's origin over the goal point
        if self.phase == "above":
            z = max(self._travel_z, grasp[2] + p.hover)
            far = np.linalg.norm(grasp[:2] - hand[:2]) > 2 * p.tolerance
            if far and hand[2] < self._travel_z - p.tolerance:  # up first, then sideways
                return np.array([hand[0], hand[1], z]), GRIP_OPEN
            return np.array([grasp[0], grasp[1], z]), GRIP_OPEN
        if self.phase == "descend":
            return grasp, GRIP_OPEN
        if self.phase in ("close", "open"):
            if self._hold is None:
                self._hold = hand.copy()
            return self._hold, GRIP_CLOSE if self.phase == "close" else GRIP_OPEN
        carry_z = max(self._carry_z, plate[2] + p.hover + self._offset_z)
        if self.phase == "lift":
            if self._hold is None:
                self._hold = hand.copy()
                self._offset_z = float(np.clip(hand[2] - bowl[2], *self.plan.hand_bounds))
            return np.array([self._hold[0], self._hold[1], carry_z]), GRIP_CLOSE
        if self.phase == "carry":
            return np.array([over_plate[0], over_plate[1], carry_z]), GRIP_CLOSE
        if self.phase == "lower":
            z = plate[2] + self.plan.place_dz + self._offset_z
            return np.array([over_plate[0], over_plate[1], z]), GRIP_CLOSE
        if self._hold is None:  # retreat
            self._hold = hand + np.array([0.0, 0.0, p.retreat_height])
        return self._hold, GRIP_OPEN

    def _dropped(self, pts: dict[str, np.ndarray]) -> bool:
        """Carrying, but the bowl is `slip` lower in the hand than when grasped (it was never held or fell)."""
        if self.phase not in ("lift", "carry", "lower") or self._hold is None and self.phase == "lift":
            return False
        return bool(pts["hand"][2] - pts["obj"][2] > self._offset_z + self.p.slip)

    def _advance(self, reached: bool, pts: dict[str, np.ndarray]) -> bool:
        """Move to the next phase when this one is done (back to the start after a drop); whether it moved."""
        if self._dropped(pts) and self._tries < self.p.retries:
            self._tries += 1
            self.phase, self._phase_steps, self._hold = PHASES[0], 0, None
            return True
        timed = {"close": self.p.close_steps, "open": self.p.open_steps}.get(self.phase)
        done = self._phase_steps >= timed if timed is not None else reached
        if not (done or self._phase_steps >= self.p.max_phase_steps) or self.phase == PHASES[-1]:
            return False
        self.phase = PHASES[PHASES.index(self.phase) + 1]
        self._phase_steps = 0
        self._hold = None
        return True

    def __call__(self, env: Any) -> np.ndarray:
        """The action (7,) for `env`'s current state; advances the phase machine."""
        if self._ori is None:
            raise RuntimeError("call reset(env, noise_seed) after env.reset() before asking for actions")
        pts = env.key_points()
        target, grip = self._target(pts)
        reached = bool(np.linalg.norm(target - pts["hand"]) < self.p.tolerance)
        if self._advance(reached, pts):  # the next phase's target, from this same state
            target, grip = self._target(pts)
        self._phase_steps += 1
        arm = self._arm(pts["hand"], target)
        if self.phase in ("lift", "carry", "lower"):  # gentler while holding: a grasp can slip
            arm[:3] = np.clip(arm[:3], -self.p.carry_speed, self.p.carry_speed)
        elif self.phase == "descend":  # slow enough for the hand to stay over the grasp point
            arm[:3] = np.clip(arm[:3], -self.p.descend_speed, self.p.descend_speed)
        if self.noise > 0:
            arm = np.clip(arm + self.rng.normal(0.0, self.noise, size=6), -1.0, 1.0)
        return np.concatenate([arm, [grip]]).astype(np.float32)


class SpatialExpert(PickPlaceExpert):
    """The LIBERO-Spatial pick-and-place expert (see the module docstring): the bowl by its rim, onto the plate."""

    name = "gazereg.envs.libero.expert.SpatialExpert"
    relation = "on"
    params_type = ExpertParams

    def _plan(self, env: Any, pts: dict[str, np.ndarray], boxes: Any) -> Plan:
        p = self.p
        offset, rot = self._choose_grasp(pts["obj"], boxes)
        bounds = (0.0, 2 * p.grasp_height)
        return Plan(offset, rot, p.grasp_height, p.grasp_height, bounds, p.release_gap)

    def _choose_grasp(self, bowl: np.ndarray, boxes: Any) -> tuple[np.ndarray, np.ndarray]:
        """The grasp: (offset (3,) of the grasp point from the bowl's origin, gripper orientation (3, 3)).

        For each of the CANDIDATES the open outer finger's path down (a grid over its footprint, from `hover`
        above the grasp to its tips) is tested against the obstacle boxes (`SceneFacts.obstacles`). The first
        candidate whose path is free and at least `min_gap` from every obstacle wins, else the first free one,
        else the one blocked lowest."""
        p = self.p
        grasp_z = bowl[2] + p.grasp_height
        levels = np.arange(grasp_z - p.tip_depth, grasp_z + p.hover, 0.01)
        grid = np.array([(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1)], dtype=np.float64)
        keys = []
        for k, (yaw, side) in enumerate(CANDIDATES):
            a = np.array([-np.sin(np.radians(yaw)), np.cos(np.radians(yaw))])  # the closing axis
            perp = np.array([-a[1], a[0]])
            finger = bowl[:2] + side * (p.rim_radius + p.finger_reach) * a
            xy = finger + grid[:, :1] * p.finger_half[0] * a + grid[:, 1:] * p.finger_half[1] * perp
            block, gap = path_clearance(boxes, xy, levels)
            keys.append((block > -np.inf, block, gap < p.min_gap, k))
        yaw, side = CANDIDATES[min(keys)[-1]]
        self.grasp_choice = {"yaw_deg": float(yaw), "side": float(side)}
        a = np.array([-np.sin(np.radians(yaw)), np.cos(np.radians(yaw)), 0.0])
        return side * p.rim_radius * a + np.array([0.0, 0.0, p.grasp_height]), yawed(yaw)
