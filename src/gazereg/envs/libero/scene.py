"""Privileged facts of a LIBERO task, read from its BDDL problem and the simulator (for experts and gaze).

    facts = SceneFacts(libero_env)         # LIBERO's robosuite env (ControlEnv.env), after it is built
    facts.roles                            # TaskRoles(obj='akita_black_bowl_1', goal='plate_1', relation='on', ...)
    facts.key_points()                     # {"obj": (3,), "goal": (3,), "hand": (3,)} world positions, metres
    facts.contact_state()                  # (gripper touches obj, both fingers touch obj)

Roles. The object to move (`obj`) and where it must go (`goal`) come from the BDDL goal, not from per-task
tables: the first binary goal predicate `(On X Y)` or `(In X Y)` whose X is a movable object gives obj = X and
goal = Y, an object, a fixture or a region (site) such as `basket_1_contain_region`. LIBERO-Spatial's goal is
always `(On <black bowl> plate_1)` (the bowl is also its `obj_of_interest`), so obj is the bowl and goal the
plate. Where the goal has no such predicate (libero_goal's `(Open wooden_cabinet_1_middle_region)`,
`(Turnon flat_stove_1)`), obj is the first of the BDDL's `obj_of_interest` and there is no goal: `key_points`
has no "goal" entry (the visuomotor gaze source then follows the parts the expert names instead, when its
episodes carry `gaze_targets`, as `GoalExpert`'s do: the handle, the knob). Tasks with two placements
(libero_10's `(And (On a b) (On c d))`) use the first one only.

Positions. An object's or fixture's position is its root body's origin (LIBERO's own `body_xpos`, the point its
predicates test); a region's is its site's position. `hand` is the midpoint of the two finger pads.

Contact. `contact`: a geom of the gripper (the gripper body and everything below it) touches a geom of obj
(its root body's subtree; for a region, its parent object's); `grasp`: geoms of both fingers touch it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

PLACEMENT_RELATIONS = ("on", "in")
SUPPORTS = ("main_table", "floor", "countertop", "coffee_table")  # what LIBERO's object states skip too


@dataclass(frozen=True)
class TaskRoles:
    """What a LIBERO task moves and where to: names as in the BDDL file."""

    obj: str | None  # the object the task acts on (None: the BDDL names none)
    goal: str | None  # where obj must go (None: no placement goal)
    relation: str | None  # "on" / "in" (the goal predicate), None without a goal


def task_roles(
    goal_state: list[list[str]], obj_of_interest: list[str], movable: set[str], places: set[str]
) -> TaskRoles:
    """Roles from a parsed BDDL goal (a list of predicates such as ["on", "akita_black_bowl_1", "plate_1"]).

    movable: names of the movable objects; places: every name a goal can refer to (objects, fixtures,
    regions). See the module docstring for the rule."""
    for pred in goal_state:
        if len(pred) == 3 and str(pred[0]).lower() in PLACEMENT_RELATIONS and pred[1] in movable:
            if pred[2] not in places:
                raise KeyError(f"goal predicate {pred} names {pred[2]!r}, which is not in the scene")
            return TaskRoles(obj=pred[1], goal=pred[2], relation=str(pred[0]).lower())
    obj = next((o for o in obj_of_interest if o in places), None)
    return TaskRoles(obj=obj, goal=None, relation=None)


@dataclass(frozen=True)
class Boxes:
    """n oriented boxes in the world: centre (n, 3) metres, rot (n, 3, 3) (columns: the box axes), half (n, 3)."""

    centre: np.ndarray
    rot: np.ndarray
    half: np.ndarray

    @staticmethod
    def concat(parts: list[Boxes]) -> Boxes:
        if not parts:
            return Boxes(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)))
        return Boxes(*(np.concatenate([getattr(b, k) for b in parts]) for k in ("centre", "rot", "half")))

    def __len__(self) -> int:
        return len(self.centre)

    def top(self) -> np.ndarray:
        """(n,) the highest world z of each box."""
        return self.centre[:, 2] + np.einsum("nj,nj->n", np.abs(self.rot[:, 2, :]), self.half)

    def corners(self) -> np.ndarray:
        """(8 n, 3) the world corners of every box."""
        signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=np.float64)
        local = signs[None] * self.half[:, None, :]  # (n, 8, 3)
        return (self.centre[:, None, :] + np.einsum("nij,ncj->nci", self.rot, local)).reshape(-1, 3)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(P, n) distance (metres) from each of P points (P, 3) to each box (0 inside)."""
        local = np.einsum("nji,pnj->pni", self.rot, points[:, None, :] - self.centre[None])
        return np.linalg.norm(np.maximum(np.abs(local) - self.half[None], 0.0), axis=-1)


def subtree_geoms(model: Any, root: int) -> np.ndarray:
    """Ids of every geom of body `root` and the bodies below it."""
    parent = np.asarray(model.body_parentid)
    inside = np.zeros(model.nbody, dtype=bool)
    inside[root] = True
    for b in range(root + 1, model.nbody):  # MuJoCo numbers a body after its parent
        inside[b] = inside[parent[b]]
    return np.flatnonzero(inside[np.asarray(model.geom_bodyid)])


def collision_boxes(model: Any, data: Any, geoms: np.ndarray) -> Boxes:
    """The oriented boxes around the collision geoms among `geoms` (ids; visual ones are skipped), world metres:
    each geom's own bounding box, in its own frame (exact for box geoms)."""
    g = geoms[(model.geom_contype[geoms] != 0) | (model.geom_conaffinity[geoms] != 0)]
    aabb = model.geom_aabb[g]  # (n, 6): centre (3), half sizes (3), in each geom's frame
    rot = data.geom_xmat[g].reshape(-1, 3, 3).copy()
    centre = data.geom_xpos[g] + np.einsum("nij,nj->ni", rot, aabb[:, :3])
    return Boxes(centre, rot, aabb[:, 3:].copy())


class SceneFacts:
    """Key points and contact of one built LIBERO task (LIBERO's robosuite environment `env`)."""

    def __init__(self, env: Any):
        import mujoco

        self._env = env
        m = env.sim.model._model
        self._model = m
        problem = env.parsed_problem
        sites = set(env.object_sites_dict)
        self.roles = task_roles(
            problem.get("goal_state", []),
            list(env.obj_of_interest or []),
            movable=set(env.objects_dict),
            places=set(env.objects_dict) | set(env.fixtures_dict) | sites,
        )

        def body_id(name: str) -> int:
            return int(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name))

        def geom_ids(names: list[str]) -> np.ndarray:
            ids = [int(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n)) for n in names]
            return np.asarray([i for i in ids if i >= 0], dtype=np.int64)

        gripper = env.robots[0].gripper
        self._grip_geoms = subtree_geoms(m, body_id(gripper.root_body))
        imp = gripper.important_geoms
        self._left = geom_ids(list(imp["left_finger"]) + list(imp["left_fingerpad"]))
        self._right = geom_ids(list(imp["right_finger"]) + list(imp["right_fingerpad"]))
        self._pads = (geom_ids(list(imp["left_fingerpad"])), geom_ids(list(imp["right_fingerpad"])))
        if not all(len(p) for p in self._pads):
            raise RuntimeError(f"gripper {type(gripper).__name__} has no finger pad geoms in the model")
        self._obj_geoms = np.zeros(0, dtype=np.int64)
        owner = None if self.roles.obj is None else self.owner(self.roles.obj)
        if owner is not None and owner in env.obj_body_id:
            self._obj_geoms = subtree_geoms(m, int(env.obj_body_id[owner]))

    def owner(self, name: str) -> str:
        """The object or fixture `name` belongs to: a region's parent (LIBERO-Object's `basket_1_contain_region`
        -> `basket_1`), an object or fixture itself."""
        sites = self._env.object_sites_dict
        return str(sites[name].parent_name) if name in sites else name

    def position(self, name: str) -> np.ndarray:
        """World position (3,) of an object, fixture (root body origin) or region (site), metres."""
        e = self._env
        if name in e.object_sites_dict:
            return np.array(e.sim.data.get_site_xpos(name), dtype=np.float64)
        if name in e.obj_body_id:
            return np.array(e.sim.data.body_xpos[e.obj_body_id[name]], dtype=np.float64)
        raise KeyError(f"{name!r} is neither an object, a fixture nor a region of this task")

    def geom_boxes(self, name: str) -> Boxes:
        """The oriented boxes around the collision geoms of an object or fixture (each geom's own bounding box,
        in its own frame: exact for box geoms)."""
        m = self._model
        return collision_boxes(
            m, self._env.sim.data._data, subtree_geoms(m, int(self._env.obj_body_id[name]))
        )

    def obstacles(self) -> Boxes:
        """The boxes of every object and fixture but obj and the tables/floor LIBERO's object states skip
        (SUPPORTS): what the gripper must not hit."""
        e = self._env
        names = [n for n in (*e.objects_dict, *e.fixtures_dict) if n not in SUPPORTS and n != self.roles.obj]
        return Boxes.concat([self.geom_boxes(n) for n in names if n in e.obj_body_id])

    def hand(self) -> np.ndarray:
        """The point between the finger pads (3,), world, metres."""
        xpos = self._env.sim.data._data.geom_xpos
        left, right = (xpos[p].mean(axis=0) for p in self._pads)
        return (left + right) / 2.0

    def key_points(self) -> dict[str, np.ndarray]:
        """World positions (3,) of `obj`, `goal` (when the task has one, see the module docstring) and `hand`."""
        out = {}
        if self.roles.obj is not None:
            out["obj"] = self.position(self.roles.obj)
        if self.roles.goal is not None:
            out["goal"] = self.position(self.roles.goal)
        out["hand"] = self.hand()
        return out

    def _contacts(self) -> tuple[np.ndarray, np.ndarray]:
        """(geom1, geom2) ids of the contacts closer than 1 mm now."""
        d = self._env.sim.data._data
        n = int(d.ncon)
        near = np.asarray(d.contact.dist[:n]) <= 1e-3
        return np.asarray(d.contact.geom1[:n])[near], np.asarray(d.contact.geom2[:n])[near]

    @staticmethod
    def _touching(contacts: tuple[np.ndarray, np.ndarray], a: np.ndarray, b: np.ndarray) -> bool:
        """Whether one of `contacts` (`_contacts`) is between a geom of `a` and one of `b` (ids)."""
        g1, g2 = contacts
        return bool(np.any((np.isin(g1, a) & np.isin(g2, b)) | (np.isin(g2, a) & np.isin(g1, b))))

    def gripper_touches(self, geoms: np.ndarray) -> bool:
        """A gripper geom touches one of `geoms` (ids) now."""
        return self._touching(self._contacts(), self._grip_geoms, geoms)

    def contact_state(self) -> tuple[bool, bool]:
        """(contact, grasp): a gripper geom touches obj; geoms of both fingers touch it."""
        if not len(self._obj_geoms):
            return False, False
        contacts, obj = self._contacts(), self._obj_geoms
        if not self._touching(contacts, self._grip_geoms, obj):
            return False, False
        return True, self._touching(contacts, self._left, obj) and self._touching(contacts, self._right, obj)


def quat_xyzw_to_axis_angle(q: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) -> axis-angle vector (3,), as robosuite's `quat2axisangle`."""
    q = np.asarray(q, dtype=np.float64)
    w = min(1.0, max(-1.0, float(q[3])))
    den = np.sqrt(1.0 - w * w)
    if den < 1e-8:
        return np.zeros(3)
    return q[:3] * 2.0 * np.arccos(w) / den
