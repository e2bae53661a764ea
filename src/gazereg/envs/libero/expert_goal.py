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

Primitives: `gazereg.envs.libero.goal_primitives` (pull, turn, push, as `Waypoint` lists).

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
(docs/benchmarks/libero_goal_expert.json, rendered in docs/libero-goal.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gazereg.envs.libero.expert import (
    GRIP_OPEN,
    ExpertParams,
    MotionParams,
    PickPlaceExpert,
    axis_angle_of,
)
from gazereg.envs.libero.expert_object import YAWS, ItemShape, ObjectParams
from gazereg.envs.libero.goal_placers import BowlPlacer, ItemPlacer
from gazereg.envs.libero.goal_primitives import GoalPrimitives, Waypoint
from gazereg.envs.libero.goal_scene import (
    GoalShifted,
    body_geoms,
    drawer_joints,
    goal_predicates,
    region_shift,
)

KINDS = ("open", "turn_on", "place", "push", "open_place")


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


class GoalExpert(GoalPrimitives, PickPlaceExpert):
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

    # ----- planning -------------------------------------------------------------------------------------
    def _start_episode(self, env: Any, noise_seed: Any) -> None:
        """What every plan starts from: the arm controller's action limits and orientation (a delta OSC_POSE
        controller, ValueError otherwise), the episode's noise stream, no waypoints, placer, gaze parts or
        grasp yet."""
        ctrl = env.unwrapped_libero.env.robots[0].controller
        if not getattr(ctrl, "use_delta", True):
            raise ValueError(f"{type(self).__name__} needs a delta OSC_POSE controller (LIBERO's default)")
        self._out_max = np.abs(np.asarray(ctrl.output_max, dtype=np.float64)[:6])
        self._ori = lambda: np.asarray(ctrl.ee_ori_mat, dtype=np.float64)
        self._noise_seed = noise_seed
        self.rng = np.random.default_rng(noise_seed)
        self._waypoints, self._placer, self._parts = [], None, {}
        self._step, self._phase_steps, self._hold = 0, 0, None
        self.grasp_choice = {}

    def reset(self, env: Any, noise_seed: Any = 0) -> None:
        """Plan `env`'s task (a LiberoEnv of LIBERO-Goal's scene, just reset) from its goal predicates."""
        self._start_episode(env, noise_seed)
        self._env = env
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
            if head == "in" and drawer_joints(env, pred[2]) and not self._is_open(env, pred[2]):
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

    @property
    def regrasps(self) -> int:
        """The re-grasps of the placement under way (its placer's; none before a placement starts)."""
        return 0 if self._placer is None else self._placer.regrasps

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

    def _touches(self, env: Any, body: int) -> bool:
        """A gripper geom touches a geom of MuJoCo body `body`."""
        return env.scene_facts.gripper_touches(body_geoms(env, body))

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
