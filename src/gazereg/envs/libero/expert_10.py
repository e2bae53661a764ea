"""A scripted expert for LIBERO-10 (LIBERO-Long): ten long-horizon tasks whose goals are conjunctions.

    env = LiberoEnv("libero_10/2", cameras=(), max_steps=520)
    expert = LongExpert(noise=0.0)
    obs, info = env.reset(seed=2)
    expert.reset(env, noise_seed=[2, 0])    # reads the task's BDDL goal, plans a step per conjunct (expert.kind)
    action = expert(env)                    # float32 (7,) in [-1, 1], LIBERO's OSC_POSE action
    expert.gaze_points(env)                 # {"knob": ((3,) world, touched?), "obj2": ...} parts the eyes visit

Plans. Every LIBERO-10 goal is `(And p1 p2 ...)`; `plan_steps` turns the predicates into an ordered list of
steps, each run with `GoalExpert`'s primitives (`gazereg.envs.libero.goal_primitives`) and placers
(`gazereg.envs.libero.goal_placers`), the next planned from the scene as the previous one leaves it:

    pull    `(In <object> <drawer region>)` whose drawer is closed: the drawer pulled open first
    turn    `(TurnOn <fixture>)`: the knob turned (before any placing: nothing stands in the hand's way yet)
    place   `(On|In <object> <target>)`, in the BDDL's order: picked up and put down; a bowl by its rim
            (`BowlPlacer`); a mug by its rim on the side away from its handle (`MugPlacer`: the cup's centre,
            its wall's radius and the handle found from the mug's collision boxes, the handle an obstacle for
            the fingers' path); the moka pot by the top of its handle, the fingers closing across it
            (`HandlePlacer`: its body is as wide as the open fingers and its lid knob keeps the palm high);
            any other item by its footprint (`ClearItemPlacer`: ObjectExpert's grasp, the yaw also keeping the
            palm's path down at the placement free, so that the hand does not come down on a mug already on
            its plate; lowering ends when the item rests on something, the basket's wall or the first item).
            Objects going to one target are spread `spread` apart along the target's longer side (two cans in
            the basket, two moka pots on the burner); an object going into an open drawer moves towards the
            drawer's front until it is clear of the cabinet above it (`_out_from_under`). The placers see the
            scene through `PlaceView`: the step's object and target as roles and key points, every other object
            and fixture (not the tables) an obstacle
    close   `(Close <drawer region>)`: "shut": the closed fingers, pointing down and then tilted `shut_tilt`
            into the cabinet (pointing straight down the forearm meets the cabinet's front before the drawer
            is in), against the handle's front, pushed along the slide joint until LIBERO calls it closed.
            `(Close <hinged fixture>)` (the microwave's door): "swing": the closed fingers against the door's
            outer face near its free edge, moved along the door's arc about the hinge until it is closed (not
            yet seen to work: the mug never gets into the microwave, see the limits)

The plan starts once the objects rest (some of LIBERO-10's initial states drop objects from above the table:
every object moving less than `settled` in a step, `settle_steps` at most). A step ends when its waypoints are
done, or, placing, when the placer's retreat has lasted `retreat_steps` (the object let go). `expert.kind` joins
the steps' kinds ("turn+place", "place+close", ...); `expert.steps` lists them.

Gaze targets (`gaze_targets`, in the order the hand visits them): the first placement's object and target are
`obj` and `goal` (the episode's key points, `env.roles`), a second placement's `obj2` and `goal2` (the goal
"touched" once the object stands within `tolerance_goal` of it), the knob `knob`, a drawer's handle `handle`, the
microwave's door `door` (touched: the gripper touches it).

Known limits. The yellow-and-white mug cannot be put into the microwave: every grasp here comes from above,
and a hand holding the mug by its rim or handle cannot pass under the microwave's roof (the mug is put down on
the roof instead). The cream cheese box fails when a tall neighbour (the milk carton) stands within the palm's
length along its narrow side: the only free yaw takes the box across its wide side, which the open fingers
barely span, and the descending fingers push it away. The measured success per task:
docs/benchmarks/libero_10_expert.json, rendered in docs/libero-10.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gazereg.envs.libero.expert import (
    DOWN_ALONG_Y,
    GRIP_OPEN,
    ExpertParams,
)
from gazereg.envs.libero.expert_goal import GoalExpert, GoalParams
from gazereg.envs.libero.expert_object import ItemShape
from gazereg.envs.libero.goal_placers import BowlPlacer, ItemPlacer
from gazereg.envs.libero.goal_primitives import Waypoint
from gazereg.envs.libero.goal_scene import (
    drawer_joints,
    goal_predicates,
    region_body,
    region_shift,
    support_top,
)
from gazereg.envs.libero.long_placers import AllObstacles, ClearItemPlacer, HandlePlacer, MugPlacer, PlaceView
from gazereg.envs.libero.long_primitives import LongPrimitives
from gazereg.envs.libero.scene import collision_boxes, subtree_geoms

STEP_KINDS = ("pull", "turn", "place", "close")


@dataclass(frozen=True)
class Step:
    """One step of a LIBERO-10 plan: kind (STEP_KINDS) and the BDDL names it acts on (a placement: object,
    target, relation "on"/"in"; pull/close: the drawer region or the fixture; turn: the fixture)."""

    kind: str
    names: tuple[str, ...]


def plan_steps(preds: list[list[str]], drawer_closed: Any = None) -> list[Step]:
    """The ordered steps for a conjunction of goal predicates (`goal_predicates`: lower-cased heads).

    `drawer_closed(region) -> bool | None`: whether `region` is a drawer that is now closed (None: not a drawer;
    no callable: none is). Order: pulls, turns, placements (the BDDL's order), closes. ValueError (one line)
    for a predicate no step handles."""
    pulls, turns, places, closes = [], [], [], []
    for pred in preds:
        head = pred[0]
        if head == "turnon" and len(pred) == 2:
            turns.append(Step("turn", (pred[1],)))
        elif head in ("on", "in") and len(pred) == 3:
            if head == "in" and drawer_closed is not None and drawer_closed(pred[2]):
                step = Step("pull", (pred[2],))
                if step not in pulls:
                    pulls.append(step)
            places.append(Step("place", (pred[1], pred[2], head)))
        elif head == "close" and len(pred) == 2:
            closes.append(Step("close", (pred[1],)))
        else:
            raise ValueError(
                f"LongExpert has no step for the goal predicate {pred} (it opens drawers, turns knobs on, "
                f"places objects and closes drawers and doors)"
            )
    return pulls + turns + places + closes


def spread_offsets(steps: list[Step], spread: float) -> list[float]:
    """Per step, where along its target's longer side (metres from the target point) its object goes: 0 for a
    target that takes one object, -spread/2, +spread/2, ... for several."""
    out = []
    for k, s in enumerate(steps):
        if s.kind != "place":
            out.append(0.0)
            continue
        same = [j for j, t in enumerate(steps) if t.kind == "place" and t.names[1] == s.names[1]]
        n = len(same)
        out.append(0.0 if n == 1 else (same.index(k) - (n - 1) / 2) * spread)
    return out


@dataclass(frozen=True)
class LongParams(GoalParams):
    """The LIBERO-10 expert's (metres, radians, steps); GoalExpert's and these."""

    mug: ExpertParams = field(default_factory=ExpertParams)  # placing a mug by its rim (sizes from its boxes)
    mug_wall_in: float = 0.007  # the mug's grasp point this far inside its wall's mean radius
    mug_grip_depth: float = 0.022  # the pad centre this far under the mug's top
    handle_out: float = 0.012  # a mug's box this far beyond its wall's radius is its handle
    retreat_steps: int = 12  # a placement ends after this many steps of the placer's retreat
    spread: float = 0.085  # objects to one target this far apart
    shut_standoff: float = 0.06  # the fingertips this far in front of the handle before pushing
    shut_extra: float = 0.02  # pushed this much beyond the closed position
    shut_tilt: float = 0.5  # radians: the fingers pointing down, tilted by this towards the push
    shut_low: float = 0.005  # the fingertips this far under the handle's centre
    finger_half_width: float = 0.01  # the closed fingers' half thickness along the push
    shut_speed: float = 0.8
    shut_steps: int = 160  # the push ends after this many steps at the latest
    swing_reach: float = 0.8  # pressing the door at this fraction of its width from the hinge
    swing_gap: float = 0.035  # the pad centre this far outside the door's face before swinging it
    swing_step: float = 0.25  # radians of the arc the hand's target leads the door by
    swing_speed: float = 0.5
    drawer_margin: float = 0.01  # an object put into a drawer clears the cabinet above it by this
    drawer_shift_max: float = (
        0.05  # and moves towards the drawer's front at most this (it stays in the region)
    )
    settle_steps: int = 60  # at most this many steps of waiting for dropped objects to come to rest
    settled: float = 0.0005  # every object moved less than this in a step: at rest
    tolerance_goal: float = 0.06  # a second placement's object this close to its target: the eyes leave it


class LongExpert(GoalExpert, LongPrimitives):
    """The LIBERO-10 expert (see the module docstring): GoalExpert's primitives, a step per goal conjunct."""

    name = "gazereg.envs.libero.expert_10.LongExpert"
    params_type = LongParams

    def __init__(self, noise: float = 0.0, params: LongParams | None = None):
        super().__init__(noise, params)
        self.steps: list[Step] = []
        self._k = 0
        self._offsets: list[float] = []
        self._real: Any = None

    # ----- planning -------------------------------------------------------------------------------------
    def reset(self, env: Any, noise_seed: Any = 0) -> None:
        """Plan `env`'s task (a LiberoEnv of a LIBERO-10 scene, just reset): the steps, then the first one."""
        self._start_episode(env, noise_seed)
        self._real = env

        def drawer_closed(region: str) -> bool | None:
            if not drawer_joints(env, region):
                return None
            return not self._is_open(env, region)

        self.steps = plan_steps(goal_predicates(env), drawer_closed)
        self._offsets = spread_offsets(self.steps, self.p.spread)
        self.kind = "+".join(s.kind for s in self.steps)
        self.gaze_targets = self._gaze_order(env)
        self._register_parts(env)
        self.grasp_choice = {}
        self._k = -1
        self._settle: list[np.ndarray] = []
        self.phase = "settle"

    def _gaze_order(self, env: Any) -> tuple[str, ...]:
        names: list[str] = []
        for s in self.steps:
            if s.kind == "place":
                first = s.names[0] == env.roles.obj and s.names[1] == env.roles.goal
                names += ["obj", "goal"] if first else ["obj2", "goal2"]
            else:
                names.append(self._part_name(env, s))
        return tuple(dict.fromkeys(names))  # a part visited twice (the handle) counts once

    def _part_name(self, env: Any, s: Step) -> str:
        if s.kind == "turn":
            return "knob"
        return "handle" if s.names[0] in env.unwrapped_libero.env.object_sites_dict else "door"

    def _next(self, env: Any) -> None:
        """Start the next step (planned from the scene as it is now)."""
        self._k += 1
        self._waypoints, self._placer = [], None
        self._step, self._phase_steps, self._hold = 0, 0, None
        if self._k >= len(self.steps):
            self.phase = "done"
            return
        s = self.steps[self._k]
        self._env = AllObstacles(env)
        if s.kind != "place":
            self._plan_primitive(env, self._env, s)
        else:
            self._start_step_placing(env, s, self._offsets[self._k])
        self.phase = self._waypoints[0].name if self._waypoints else self._placer.phase  # type: ignore[union-attr]

    def _register_parts(self, env: Any) -> None:
        """Every step's gaze parts, from the first frame on (the collector stores one value per frame): the
        primitives' (planned once here for their parts, planned again when their step starts) and a second
        placement's `obj2`, `goal2`."""
        view = AllObstacles(env)
        self._env = view
        facts, tol = env.scene_facts, self.p.tolerance_goal
        for k, s in enumerate(self.steps):
            if s.kind == "place":
                obj, goal, _ = s.names
                if obj == env.roles.obj and goal == env.roles.goal:
                    continue
                pv = self._place_view(env, s, self._offsets[k])
                self._parts["obj2"] = lambda o=obj: (facts.position(o), self._touches(env, _root(env, o)))
                self._parts["goal2"] = lambda o=obj, v=pv: (
                    v.key_points()["goal"],
                    bool(np.linalg.norm(facts.position(o)[:2] - v.key_points()["goal"][:2]) < tol),
                )
            else:
                self._plan_primitive(env, view, s)
        self._waypoints = []

    def _plan_primitive(self, env: Any, view: Any, s: Step) -> None:
        """The waypoints of primitive step `s` (pull, turn, close), from the scene as it is now."""
        if s.kind == "pull":
            self._plan_pull(view, s.names[0])
            # the wrist back to pointing down for the placing that follows
            self._waypoints.append(Waypoint("unturn", self._held, DOWN_ALONG_Y, GRIP_OPEN, tolerance=0.025))
        elif s.kind == "turn":
            self._plan_turn(view, s.names[0])
        elif s.names[0] in env.unwrapped_libero.env.object_sites_dict:
            self._plan_shut(view, s.names[0])
        else:
            self._plan_swing(view, s.names[0])

    def _place_view(self, env: Any, s: Step, along: float) -> PlaceView:
        obj, goal, relation = s.names
        shift = region_shift(env, goal, self.p.region_rise) if relation == "on" else np.zeros(3)
        if along:
            shift = shift + self._spread_dir(env, goal) * along
        if relation == "in":
            shift = shift + self._out_from_under(env, obj, goal)
        return PlaceView(env, obj, goal, relation, shift)

    def _out_from_under(self, env: Any, obj: str, region: str) -> np.ndarray:
        """Into an open drawer: the target moved along the opening direction until the object's footprint
        (`drawer_margin` to spare) is clear of the cabinet above the drawer (the closed drawer over it, whose
        front lip would catch a bowl's rim), at most to `drawer_shift_max`; zero for any other target."""
        if not drawer_joints(env, region):
            return np.zeros(3)
        e, m = env.unwrapped_libero.env, env.physics_model
        owner = env.scene_facts.owner(region)
        joint, _, _, towards_closed = self._drawer_slide(env, region, "default_close_ranges")
        u = -towards_closed  # out of the cabinet
        target = env.scene_facts.position(region)
        shape = ItemShape.of(env.scene_facts.geom_boxes(obj))
        radius = float(
            np.max(np.linalg.norm(shape.corners[:, :2] - env.scene_facts.position(obj)[:2], axis=1))
        )
        floor = support_top(env, region, target[:2])
        root = region_body(env, region)
        while int(m.body_parentid[root]) != 0 and root != int(e.obj_body_id[owner]):
            root = int(m.body_parentid[root])
        geoms = subtree_geoms(m, root)
        geoms = geoms[np.asarray(m.geom_bodyid)[geoms] != joint.body]  # the cabinet but the drawer itself
        boxes = collision_boxes(m, env.physics_data, geoms)
        c = boxes.corners().reshape(-1, 8, 3)
        low = c[:, :, 2].min(axis=1)
        tall = float(shape.top - shape.bottom)
        over = (low > floor + 0.005) & (low < floor + tall + self.p.drawer_margin)
        if not over.any():
            return np.zeros(3)
        front = float((c[over] @ u).max())  # the farthest the cabinet over the drawer reaches out
        need = front + radius + self.p.drawer_margin - float(target @ u)
        return u * float(np.clip(need, 0.0, self.p.drawer_shift_max))

    def _start_step_placing(self, env: Any, s: Step, along: float) -> None:
        obj = s.names[0]
        view = self._place_view(env, s, along)
        kind = type(env.unwrapped_libero.env.get_object(obj)).__name__.lower()
        placer: BowlPlacer | ItemPlacer
        if "bowl" in kind or "bowl" in obj:
            placer = BowlPlacer(self.noise, self.p.bowl)
        elif "moka" in kind or "moka" in obj:
            placer = HandlePlacer(self.noise, self.p.item)
        elif "mug" in kind or "mug" in obj:
            placer = MugPlacer(self.noise, self.p.mug)
            placer.grip_depth, placer.wall_in = self.p.mug_grip_depth, self.p.mug_wall_in
            placer.handle_out = self.p.handle_out
        else:
            placer = ClearItemPlacer(self.noise, self.p.item)
        placer.reset(view, self._noise_seed)
        placer.rng = self.rng  # one noise stream for the whole episode
        self._placer, self._view = placer, view
        self.grasp_choice = {**self.grasp_choice, **{f"{obj}.{k}": v for k, v in placer.grasp_choice.items()}}

    def _spread_dir(self, env: Any, goal: str) -> np.ndarray:
        """The horizontal unit vector (3,) along the target's longer side: a region's site box when it is not
        square, else (a square region, an object) world x."""
        e = env.unwrapped_libero.env
        site = e.object_sites_dict.get(goal)
        if site is not None and hasattr(site, "size"):
            M = np.asarray(e.sim.data.get_site_xmat(goal), dtype=np.float64)
            size = np.asarray(site.size, dtype=np.float64)
            if abs(size[0] - size[1]) > 1e-3:
                v = M[:, int(np.argmax(size[:2]))]
                v = np.array([v[0], v[1], 0.0])
                return v / max(float(np.linalg.norm(v)), 1e-9)
        return np.array([1.0, 0.0, 0.0])

    # ----- control --------------------------------------------------------------------------------------
    def _step_done(self) -> bool:
        if self._placer is not None:
            return self._placer.phase == "retreat" and self._placer._phase_steps >= self.p.retreat_steps
        return self._step >= len(self._waypoints)

    def __call__(self, env: Any) -> np.ndarray:
        """The action (7,) for `env`'s current state; advances the plan, step by step."""
        if self._ori is None:
            raise RuntimeError("call reset(env, noise_seed) after env.reset() before asking for actions")
        if self._k < 0:  # LIBERO-10's initial states drop some objects: the plan waits until they rest
            e = env.unwrapped_libero.env
            pos = np.array([env.scene_facts.position(n) for n in e.objects_dict if n in e.obj_body_id])
            self._settle.append(pos)
            moving = (
                len(self._settle) < 2 or np.abs(self._settle[-1] - self._settle[-2]).max() > self.p.settled
            )
            if moving and len(self._settle) <= self.p.settle_steps:
                return np.array([0, 0, 0, 0, 0, 0, GRIP_OPEN], dtype=np.float32)
            self._next(env)
        while self._k < len(self.steps) and self._step_done():
            self._next(env)
        if self._k >= len(self.steps):
            return np.array([0, 0, 0, 0, 0, 0, GRIP_OPEN], dtype=np.float32)
        return super().__call__(env)


def _root(env: Any, name: str) -> int:
    """The MuJoCo body id of object `name`'s root."""
    return int(env.unwrapped_libero.env.obj_body_id[name])
