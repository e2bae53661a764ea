"""A scripted expert for LIBERO-Goal: one kitchen scene, ten goals, each composed from a few motion primitives.

    env = LiberoEnv("libero_goal/0", cameras=())
    expert = GoalExpert(noise=0.0)
    obs, info = env.reset(seed=2)
    expert.reset(env, noise_seed=[2, 0])    # reads the task's BDDL goal, builds its plan (expert.kind)
    action = expert(env)                    # float32 (7,) in [-1, 1], LIBERO's OSC_POSE action
    expert.gaze_points(env)                 # {"handle": ((3,) world, touched?)} parts the eyes visit, if any

Plans. The expert reads the task's goal predicates (LIBERO's parsed BDDL, `parsed_problem["goal_state"]`), not
per-task tables, and composes a plan from them (`expert.kind`):

    open       `(Open <drawer region>)`: "pull" the drawer's handle out along its slide joint
    turn_on    `(TurnOn <fixture>)`: "turn" the knob
    place      `(On|In <object> <target>)`: `PickPlaceExpert`'s phase machine (above, descend, close, lift,
               carry, lower, open, retreat): a bowl by its rim (`SpatialExpert`'s grasp, the palm's path
               down tested too: `BowlPlacer`), any other item by its footprint (`ObjectExpert`'s grasp:
               `ItemPlacer`), put down `release_gap` above the target's support surface (`support_top`:
               where the vertical line through the target point leaves the highest collision box of the
               target: the stove's burner, the cabinet's top, the plate, the bowl's floor, a drawer's floor,
               the rack's slanted board). `On` a region is LIBERO's test of a box in the region site's own
               frame: the target point moves into it (`region_shift`; up the wine rack's slanted top board,
               nowhere for a level region)
    push       `(On <object> <table region>)` when the instruction says "push" or the object is wider than the
               open gripper at every yaw (the plate): "push"
    open_place `(In <object> <drawer region>)` whose drawer is closed: "pull" first, then "place" (LIBERO-Goal's
               "open the top drawer and put the bowl inside"); a bowl the open drawer hangs over is lifted up
               and out from under it at once, and grasped from the side it leaves towards

A predicate with no primitive (Close, TurnOff, ...) is refused at `reset` with one line naming it.

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

Heights while moving sideways clear the obstacle boxes (`SceneFacts.obstacles`) near the path by `clearance`:
the primitives' and, after a pull (little time left), the placing's those whose footprint comes within
`corridor` of the path (`corridor_top`); otherwise the placing's as `PickPlaceExpert`'s (a disc around each
box: the wine rack's lifts a path that passes beside it). Units: metres, radians, steps (20 per second).

Known limits. "Open the top drawer and put the bowl inside" fails when the bowl starts close to the cabinet:
the open drawer's corner hangs over its rim, and every rim grasp would bring the hand (0.2 m long across the
fingers) down onto the drawer; the suite's 300 steps leave no time to move the bowl aside before opening the
drawer. A grasp can be lost on the way (the flat cream cheese box when the hand stops just above its low grasp
point); after `retries` regrasps the episode runs out of steps. The drawer is pulled with the gripper turned
horizontal; the hand's side can touch what stands next to the handle (the plate in front of the cabinet),
which does not change the drawer's goal.

Success per task, measured with `benchmarks/bench_libero.py --suite libero_goal --expert-inits N`
(docs/benchmarks/libero_goal_expert.json, rendered in docs/libero.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gazereg.envs.libero.expert import (
    CANDIDATES,
    DOWN_ALONG_Y,
    GRIP_CLOSE,
    GRIP_OPEN,
    ExpertParams,
    MotionParams,
    PickPlaceExpert,
    Plan,
    SpatialExpert,
    axis_angle_of,
    path_clearance,
    yawed,
)
from gazereg.envs.libero.expert_object import YAWS, ItemShape, ObjectExpert, ObjectParams, closing_axes
from gazereg.envs.libero.scene import Boxes, subtree_mask

KINDS = ("open", "turn_on", "place", "push", "open_place")
# The Panda palm's footprint (half sizes along and across the closing axis) and its bottom above the pad centre
# (ObjectParams' defaults), for the bowl's grasp.
PALM_HALF, PALM_LOW = ObjectParams.palm_half, ObjectParams.palm_low
PALM_TALL = 0.2  # the hand and the wrist above the palm's bottom, what an overhang must clear


@dataclass(frozen=True)
class GoalParams(MotionParams):
    """The LIBERO-Goal expert's (metres, radians, steps); the placing plans' own parameters are `bowl` and
    `item`; defaults fit LIBERO-Goal's kitchen scene and the Panda gripper."""

    bowl: ExpertParams = field(default_factory=ExpertParams)  # placing a bowl (held by its rim)
    item: ObjectParams = field(default_factory=ObjectParams)  # placing anything else (by its footprint)
    rot_tolerance: float = 0.08  # a waypoint's orientation is reached within this angle
    via_tolerance: float = 0.025  # a point passed on the way (not where the hand acts) is reached within this
    pull_standoff: float = 0.08  # the pad centre this far in front of the handle before going in
    pull_out: float = 0.004  # the pads this far in front of the handle's centre when closing on it
    pull_extra: float = 0.01  # pulled this much beyond the middle of the open range
    pull_speed: float = 0.5
    back_off: float = 0.08  # after letting go, away from the handle along the opening direction
    ridge_min: float = 0.01  # a knob box standing this much above the knob's lowest top is its ridge
    knob_pad_below: float = 0.012  # the pad centre under the ridge's top
    turn_past: float = 0.3  # turned to this beyond the lower end of the turn-on range
    turn_speed: float = 0.3  # the rotation action's largest component while turning (of 1)
    turn_slack: float = 0.05  # the turn ends with the knob this close to its goal angle
    push_height: float = 0.012  # the fingertips above the table while pushing
    push_gap: float = 0.03  # the fingers start this far behind the object's footprint
    push_speed: float = 0.4
    push_steps: int = 150  # the push ends after this many steps at the latest
    dish_depth: float = 0.005  # an object whose top is this much above its centre's top is a dish (a plate)
    dish_height: float = -0.008  # the fingertips above a dish's floor while dragging it (below: pressing)
    push_lead: float = 0.06  # the hand's target leads its offset to the pushed object by this
    finger_tip: float = 0.017  # the Panda's fingertips below the pad centre (tip_depth has a margin)
    max_width: float = 0.07  # wider than this at every yaw: pushed, not picked up
    region_rise: float = 0.03  # placing on a region: the target this far above its face (`region_shift`)


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


def body_boxes(env: Any, body: int) -> Boxes:
    """The oriented boxes around the collision geoms of MuJoCo body `body` alone (world, metres)."""
    m, d = env.physics_model, env.physics_data
    g = np.flatnonzero(np.asarray(m.geom_bodyid) == body)
    g = g[(m.geom_contype[g] != 0) | (m.geom_conaffinity[g] != 0)]
    rot = d.geom_xmat[g].reshape(-1, 3, 3).copy()
    centre = d.geom_xpos[g] + np.einsum("nij,nj->ni", rot, m.geom_aabb[g, :3])
    return Boxes(centre, rot, m.geom_aabb[g, 3:].copy())


def subtree_bodies(model: Any, root: int) -> np.ndarray:
    """Ids of body `root` and every body below it."""
    return np.flatnonzero(subtree_mask(model, root))


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


def support_top(env: Any, name: str, xy: np.ndarray) -> float:
    """The highest top (z, metres) among the collision boxes of `name` (a region: its site's body and the bodies
    below it; an object or fixture: its own) whose footprint holds the point `xy` (2,); `name`'s own z if
    none does."""
    import mujoco

    m = env.physics_model
    facts = env.scene_facts
    e = env.unwrapped_libero.env
    if name in e.object_sites_dict:
        root = int(m.site_bodyid[int(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name))])
    else:
        root = int(e.obj_body_id[facts.owner(name)])
    boxes = Boxes.concat([body_boxes(env, int(b)) for b in subtree_bodies(m, root)])
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


class GoalExpert(PickPlaceExpert):
    """The LIBERO-Goal expert (see the module docstring): a plan per goal predicate, from primitives."""

    name = "gazereg.envs.libero.expert_goal.GoalExpert"
    relation = "any"
    params_type = GoalParams

    def __init__(self, noise: float = 0.0, params: GoalParams | None = None):
        super().__init__(noise, params)
        self.kind: str | None = None
        self._waypoints: list[Waypoint] = []
        self._placer: PickPlaceExpert | None = None
        self._parts: dict[str, Callable[[], tuple[np.ndarray, bool]]] = {}
        self.gaze_targets: tuple[str, ...] = ("obj", "goal")
        self._grip_cache: np.ndarray | None = None  # the gripper's geom ids, of this task's model

    # ----- planning -------------------------------------------------------------------------------------
    def reset(self, env: Any, noise_seed: Any = 0) -> None:
        """Plan `env`'s task (a LiberoEnv of LIBERO-Goal's scene, just reset) from its goal predicates."""
        ctrl = env.unwrapped_libero.env.robots[0].controller
        if not getattr(ctrl, "use_delta", True):
            raise ValueError(f"{type(self).__name__} needs a delta OSC_POSE controller (LIBERO's default)")
        self._out_max = np.abs(np.asarray(ctrl.output_max, dtype=np.float64)[:6])
        self._ori = lambda: np.asarray(ctrl.ee_ori_mat, dtype=np.float64)
        self._noise_seed = noise_seed
        self.rng = np.random.default_rng(noise_seed)
        self._env = env
        self._waypoints, self._placer, self._parts = [], None, {}
        self._step, self._phase_steps, self._hold = 0, 0, None
        self._grip_cache = None
        self.grasp_choice = {}
        preds = goal_predicates(env)
        if len(preds) != 1:
            raise ValueError(f"GoalExpert plans one goal predicate; task {env.task!r} has {preds}")
        pred = preds[0]
        head = pred[0]
        if head == "open":
            self.kind = "open"
            self._plan_pull(env, pred[1])
            self.gaze_targets = ("handle",)
        elif head == "turnon":
            self.kind = "turn_on"
            self._plan_turn(env, pred[1])
            self.gaze_targets = ("knob",)
        elif head in ("on", "in"):
            region = env.unwrapped_libero.env.object_sites_dict.get(pred[2])
            joints = list(getattr(region, "joints", None) or [])
            if head == "in" and joints and not self._is_open(env, pred[2]):
                self.kind = "open_place"
                self._plan_pull(env, pred[2])
                self.gaze_targets = ("handle", "obj", "goal")
            elif self._pushed(env):
                self.kind = "push"
                self._plan_push(env)
                self.gaze_targets = ("obj", "goal")
            else:
                self.kind = "place"
                self._start_placing(env)
                self.gaze_targets = ("obj", "goal")
        else:
            raise ValueError(
                f"GoalExpert has no primitive for the goal predicate {pred} of task {env.task!r} "
                f"(it opens drawers, turns knobs on, pushes and places objects)"
            )
        first = self._waypoints[0].name if self._waypoints else None
        self.phase = first or self._placer.phase  # type: ignore[union-attr]

    def _is_open(self, env: Any, region: str) -> bool:
        return bool(env.unwrapped_libero.env.object_states_dict[region].is_open())

    def _pushed(self, env: Any) -> bool:
        """Push rather than pick up: the instruction says so, or the object is too wide for the open fingers."""
        if env.instruction.strip().lower().startswith("push"):
            return True
        if self._is_bowl(env):  # held by its rim, whatever its width
            return False
        shape = ItemShape.of(env.scene_facts.geom_boxes(env.roles.obj))
        return min(shape.footprint(y)[0] for y in YAWS) > self.p.max_width

    @staticmethod
    def _is_bowl(env: Any) -> bool:
        """The object is a bowl (its class or BDDL name says so): held by its rim."""
        obj = env.roles.obj
        return "bowl" in type(env.unwrapped_libero.env.get_object(obj)).__name__.lower() or "bowl" in obj

    def _start_placing(self, env: Any) -> None:
        placer: BowlPlacer | ItemPlacer = (
            BowlPlacer(self.noise, self.p.bowl) if self._is_bowl(env) else ItemPlacer(self.noise, self.p.item)
        )
        # after a pull little time is left: heights from the boxes' footprints, not discs around them
        placer.exact_corridor = self.kind == "open_place"
        on = env.roles.relation == "on"
        shift = region_shift(env, env.roles.goal, self.p.region_rise) if on else np.zeros(3)
        self._view = GoalShifted(env, shift)
        placer.reset(self._view, self._noise_seed)
        placer.rng = self.rng  # one noise stream for the whole episode
        self._placer = placer
        self.grasp_choice = {**self.grasp_choice, **placer.grasp_choice}

    def _travel_z(self, a: np.ndarray, b: np.ndarray, hang: float) -> float:
        """The height (pad centre) for moving sideways from a to b: the obstacles near the path, cleared."""
        boxes = self._env.scene_facts.obstacles()
        return corridor_top(boxes, a, b, self.p.corridor) + self.p.clearance + hang

    def _plan_pull(self, env: Any, region: str) -> None:
        """Waypoints that pull `region`'s drawer open (see the module docstring, "pull")."""
        e = env.unwrapped_libero.env
        site = e.object_sites_dict[region]
        owner = env.scene_facts.owner(region)
        ranges = e.get_object(owner).object_properties["articulation"]["default_open_ranges"]
        joint = Joint.named(env, list(site.joints)[0])
        q0, q_goal = joint.value(env), float(np.mean(ranges))
        u = joint.axis * np.sign(q_goal - q0)
        u = u / np.linalg.norm(u)
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
    def _touches(self, env: Any, body: int) -> bool:
        """A gripper geom touches a collision geom of MuJoCo body `body`."""
        m, d = env.physics_model, env.physics_data
        n = int(d.ncon)
        if n == 0:
            return False
        grip = self._gripper_geoms(env)
        g1, g2 = np.asarray(d.contact.geom1[:n]), np.asarray(d.contact.geom2[:n])
        gb = np.asarray(m.geom_bodyid)
        near = np.asarray(d.contact.dist[:n]) <= 1e-3
        hit = (np.isin(g1, grip) & (gb[g2] == body)) | (np.isin(g2, grip) & (gb[g1] == body))
        return bool(np.any(near & hit))

    def _gripper_geoms(self, env: Any) -> np.ndarray:
        import mujoco

        if self._grip_cache is None:
            m = env.physics_model
            root = int(
                mujoco.mj_name2id(
                    m, mujoco.mjtObj.mjOBJ_BODY, env.unwrapped_libero.env.robots[0].gripper.root_body
                )
            )
            bodies = subtree_bodies(m, root)
            self._grip_cache = np.flatnonzero(np.isin(np.asarray(m.geom_bodyid), bodies))
        return self._grip_cache

    def gaze_points(self, env: Any) -> dict[str, tuple[np.ndarray, bool]]:
        """The task's parts the eyes visit besides `obj` and `goal` (the drawer's handle, the knob), now:
        name -> (world position (3,) metres, whether the gripper touches the part)."""
        return {name: fn() for name, fn in self._parts.items()}

    # ----- control --------------------------------------------------------------------------------------
    def _held(self, pts: dict[str, np.ndarray], shift: np.ndarray | None = None) -> np.ndarray:
        """The hand's position when the waypoint began (plus `shift`)."""
        if self._hold is None:
            self._hold = pts["hand"].copy()
        return self._hold + (0.0 if shift is None else shift)

    def __call__(self, env: Any) -> np.ndarray:
        """The action (7,) for `env`'s current state; advances the plan."""
        if self._ori is None:
            raise RuntimeError("call reset(env, noise_seed) after env.reset() before asking for actions")
        if self._step >= len(self._waypoints):
            if self._placer is None:  # the plan is done (its goal not reached): hold still, open
                if self.kind == "open_place":
                    self._start_placing(env)
                else:
                    return np.array([0, 0, 0, 0, 0, 0, GRIP_OPEN], dtype=np.float32)
            action = self._placer(self._view)  # type: ignore[misc]
            self.phase = self._placer.phase  # type: ignore[union-attr]
            return action
        pts = env.key_points()
        wp = self._waypoints[self._step]
        if self._finished(wp, pts):
            self._step += 1
            self._phase_steps, self._hold = 0, None
            return self(env)
        self.phase = wp.name
        self._phase_steps += 1
        self._R = wp.rot
        arm = self._arm(pts["hand"], wp.target(pts))
        arm[:3] = np.clip(arm[:3], -wp.speed, wp.speed)
        arm[3:] = np.clip(arm[3:], -wp.rot_speed, wp.rot_speed)
        if self.noise > 0:
            arm = np.clip(arm + self.rng.normal(0.0, self.noise, size=6), -1.0, 1.0)
        return np.concatenate([arm, [wp.grip]]).astype(np.float32)

    def _finished(self, wp: Waypoint, pts: dict[str, np.ndarray]) -> bool:
        if self._phase_steps >= max(self.p.max_phase_steps, wp.steps or 0):
            return True
        if wp.done is not None and wp.done():
            return True
        if wp.steps is not None:
            return self._phase_steps >= wp.steps
        if self._phase_steps == 0:
            return False
        tol = self.p.tolerance if wp.tolerance is None else wp.tolerance
        near = np.linalg.norm(wp.target(pts) - pts["hand"]) < tol
        angle = float(np.linalg.norm(axis_angle_of(wp.rot @ self._ori().T)))
        turned = angle < self.p.rot_tolerance * tol / self.p.tolerance  # a via point: looser here too
        return bool(near and turned)
