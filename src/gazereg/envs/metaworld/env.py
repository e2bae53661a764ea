"""A gymnasium environment over any Meta-World v3 task, with camera images, proprioception and an instruction.

    env = MetaWorldEnv("pick-place-v3", cameras=("corner2",), image_size=96)
    obs, info = env.reset(seed=3)        # setup seed 3: object and goal positions fixed by the seed
    obs["images"]["corner2"]             # uint8 (96, 96, 3), upright, as the policy sees it
    obs["state"]                         # float32 (4,): hand x, y, z (metres, world frame) + gripper opening
    obs["instruction"]                   # "Pick up the puck and place it at the goal."
    obs, reward, terminated, truncated, info = env.step(action)   # action float32 (4,) in [-1, 1]
    info["success"]                      # Meta-World's success test after this step

Setups (seeds). Meta-World fixes a task's initial object and goal positions through benchmark "tasks": the
MT1 benchmark built with `metaworld.MT1(task, seed=b)` holds 50 fixed setups drawn from `b`. A setup seed
`s` here is setup `s % 50` of `MT1(task, seed=s // 50)`: seeds 0-49 are exactly Meta-World's 50 MT1 setups
for benchmark seed 0, seeds 50-99 those for benchmark seed 1, and so on. The same seed gives the same setup in
any process. `reset(seed=s)` selects setup `s`; `reset()` without a seed takes the next one (s + 1), starting
from the constructor's `seed`. (This is what `gymnasium.make("Meta-World/MT1", env_name=..., seed=b)` builds,
minus its wrapper that picks one of the 50 setups at random at each reset.)

State. `state = [hand_x, hand_y, hand_z, gripper]`: the hand (end-effector body) position in the world frame
in metres, as Meta-World's own observation reports it, and the gripper opening: the distance between the two
fingers divided by 0.1 m and clipped to [0, 1] (1 open, about 0 closed on nothing).

Actions. Meta-World's: (dx, dy, dz, grip) in [-1, 1]; the hand's mocap target moves by 1 cm per unit and grip
> 0 closes the fingers. 80 steps per second of simulated time (frame skip 5 x 2.5 ms).

Rendering. Images come from a render-only copy of the model (see `gazereg.envs.render`) with the fast
settings, so lighting perturbations and the goal marker never touch physics. Meta-World's goal sites (the
ones the task keeps at its goal, e.g. `goal` in reach/push/pick-place) are drawn as spheres of radius
`goal_marker_radius` (default 3 cm; 0 keeps Meta-World's 2 cm markers with their own colours), which keeps the
goal visible at 64-128 px where the original marker is about one pixel. Cameras whose image-up axis points
down (corner, corner2, corner3, corner4) are rotated 180 degrees; `camera_geometry(name)` owns that and the
projection of world points into the image (`project`).

`info` after reset and every step: success, raw_obs (Meta-World's 39-d observation, for scripted experts),
setup_seed, contact (a gripper geom touches a movable non-robot body), grasp (both fingers touch one),
the positions (world, metres) obj_pos, goal_pos, hand_pos (the point between the finger pads), and Meta-World's
reward terms.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from gazereg.envs.camera import CameraGeometry, camera_geometry
from gazereg.envs.interface import check_cameras, check_render_mode, image_hw
from gazereg.envs.metaworld.instructions import instruction_for
from gazereg.envs.perturbations import LightState, Perturbation
from gazereg.envs.render import (
    FastRenderer,
    VisualMirror,
    build_visual_model,
    resolve_mesh_cell,
    select_gl_backend,
)
from gazereg.envs.spaces import env_spaces

SETUPS_PER_BENCHMARK_SEED = 50
MAX_PATH_LENGTH = 500  # Meta-World refuses to step past this
STATE_LAYOUT = ("hand_x", "hand_y", "hand_z", "gripper_open")
ACTION_LAYOUT = ("dx", "dy", "dz", "grip")
DEFAULT_GOAL_RGBA = (0.1, 0.85, 0.1, 1.0)
_LEFT = ("leftclaw", "leftpad")
_RIGHT = ("rightclaw", "rightpad")


def setup_of(seed: int) -> tuple[int, int]:
    """Setup seed -> (Meta-World MT1 benchmark seed, index of the setup among its 50)."""
    if seed < 0:
        raise ValueError(f"setup seeds are >= 0, got {seed}")
    return seed // SETUPS_PER_BENCHMARK_SEED, seed % SETUPS_PER_BENCHMARK_SEED


def _v3_environments() -> dict[str, Any]:
    """Meta-World's v3 task name -> environment class."""
    from metaworld.env_dict import ALL_V3_ENVIRONMENTS

    return ALL_V3_ENVIRONMENTS


def meta_world_tasks() -> list[str]:
    return list(_v3_environments())


@functools.lru_cache(maxsize=64)
def benchmark_setups(task: str, benchmark_seed: int) -> tuple[Any, ...]:
    """Meta-World's 50 fixed setups of `task` for `benchmark_seed` (cached per process; about 1 s to build)."""
    import metaworld

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return tuple(metaworld.MT1(task, seed=benchmark_seed).train_tasks)


def _subtree(model: Any, root: int) -> set[int]:
    out = {root}
    for b in range(model.nbody):
        p = b
        while p > 0:
            if p == root:
                out.add(b)
                break
            p = int(model.body_parentid[p])
    return out


class MetaWorldEnv(gym.Env):
    """Meta-World v3 task with RGB cameras, 4-d proprioception and a language instruction (see module doc)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 80}

    def __init__(
        self,
        task: str = "reach-v3",
        cameras: Sequence[str] = ("corner2",),
        image_size: int | tuple[int, int] = 128,
        seed: int = 0,
        max_steps: int = MAX_PATH_LENGTH,
        terminate_on_success: bool = True,
        perturbation: Perturbation | None = None,
        noise_seed: int = 0,
        goal_marker_radius: float = 0.03,
        goal_marker_rgba: tuple[float, float, float, float] = DEFAULT_GOAL_RGBA,
        mesh_cell: float | str | None = "auto",
        gl_backend: str | None = None,
        instruction: str | None = None,
        render_mode: str | None = "rgb_array",
    ):
        envs = _v3_environments()
        if task not in envs:
            raise KeyError(f"unknown Meta-World task {task!r}; v3 tasks: {sorted(envs)}")
        if not 1 <= max_steps <= MAX_PATH_LENGTH:
            raise ValueError(
                f"max_steps must be in [1, {MAX_PATH_LENGTH}] (Meta-World's limit), got {max_steps}"
            )
        check_render_mode(render_mode)
        H, W = image_hw(image_size)
        self.task = task
        self.cameras = check_cameras(cameras)
        self.image_size = (H, W)
        self.max_steps = int(max_steps)
        self.terminate_on_success = bool(terminate_on_success)
        self.noise_seed = int(noise_seed)
        self.instruction = instruction or instruction_for(task)
        self.render_mode = render_mode
        self.goal_marker_radius = float(goal_marker_radius)
        self.gl_backend = (gl_backend or select_gl_backend()) if self.cameras else None
        self._perturbation = perturbation or Perturbation()

        self._start_metaworld(envs[task], seed)
        import mujoco

        self._mj = mujoco
        self._find_contact_geoms()
        self._renderer: FastRenderer | None = None
        self._geometry: dict[str, CameraGeometry] = {}
        self._cam_ids: dict[str, int] = {}
        if self.cameras:
            self._start_rendering(mesh_cell, goal_marker_radius, goal_marker_rgba)
        self._noise_rng = np.random.default_rng([self.noise_seed, self._setup_seed])
        self._steps = 0
        self._last_obs: dict[str, Any] | None = None
        self.observation_space, self.action_space = env_spaces(
            self.cameras, H, W, len(STATE_LAYOUT), len(ACTION_LAYOUT)
        )

    def _start_metaworld(self, env_class: Any, seed: int) -> None:
        """Meta-World's environment of the task, reset to setup `seed`; fps from its simulation timestep."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            self._mw = env_class()
        self._setup_seed = int(seed)
        self._next_seed = int(seed)
        self._select_setup(self._setup_seed)
        self._raw_obs, _ = self._mw.reset()
        self.fps = 1.0 / (float(self._mw.model.opt.timestep) * int(self._mw.frame_skip))
        self.metadata = {**self.metadata, "render_fps": self.fps}

    def _find_contact_geoms(self) -> None:
        """The geoms `contact_state` tests: the gripper's, each finger's, and those of movable objects."""
        m = self._mw.model
        mj = self._mj
        # The gripper: the wrist body `right_hand` (its geoms touch handles and windows) and everything below it.
        wrist = "right_hand" if mj.mj_name2id(m, mj.mjtObj.mjOBJ_BODY, "right_hand") >= 0 else "hand"
        hand_root = _subtree(m, m.body(wrist).id)
        robot_root = int(m.body_rootid[m.body("hand").id])
        geom_body = np.asarray(m.geom_bodyid)
        self._grip_geoms = np.flatnonzero(np.isin(geom_body, sorted(hand_root)))
        self._left_geoms = np.flatnonzero(np.isin(geom_body, [m.body(b).id for b in _LEFT]))
        self._right_geoms = np.flatnonzero(np.isin(geom_body, [m.body(b).id for b in _RIGHT]))
        movable = (np.asarray(m.body_weldid) != 0) & (np.asarray(m.body_rootid) != robot_root)
        movable &= np.asarray(m.body_mocapid) < 0
        self._object_geoms = np.flatnonzero(movable[geom_body])

    def _start_rendering(
        self, mesh_cell: float | str | None, goal_radius: float, goal_rgba: Sequence[float]
    ) -> None:
        """The render-only copy of the model (simplified meshes, goal markers), its renderer and cameras."""
        H, W = self.image_size
        m = self._mw.model
        visual = build_visual_model(self._mw.model_name, m, mesh_cell=resolve_mesh_cell(mesh_cell, H, W))
        self._mirror = VisualMirror(m, visual)
        self._mirror.sync_model()
        self._mark_goals(goal_radius, goal_rgba)
        self._base_lights = LightState.capture(visual)
        self._renderer = FastRenderer(visual, H, W, backend=self.gl_backend)
        vd = self._mirror.sync_data(self._mw.data)
        for cam in self.cameras:
            self._geometry[cam] = camera_geometry(visual, vd, cam, H, W)
            self._cam_ids[cam] = self._mj.mj_name2id(visual, self._mj.mjtObj.mjOBJ_CAMERA, cam)

    # ----- setup ------------------------------------------------------------------------------------------
    def _select_setup(self, seed: int) -> None:
        b, k = setup_of(seed)
        # MT1 setups make the goal observable (the experts read it from the last 3 entries).
        self._mw.set_task(benchmark_setups(self.task, b)[k])

    def _mark_goals(self, radius: float, rgba: Sequence[float]) -> None:
        if radius <= 0:
            return
        v = self._mirror.visual_model
        for name, _ in self._mw._target_site_config:
            sid = self._mj.mj_name2id(v, self._mj.mjtObj.mjOBJ_SITE, name)
            if sid < 0:
                continue
            v.site_type[sid] = self._mj.mjtGeom.mjGEOM_SPHERE
            v.site_size[sid] = [radius, radius, radius]
            v.site_rgba[sid] = list(rgba)
            v.site_group[sid] = 0

    @property
    def setup_seed(self) -> int:
        return self._setup_seed

    @property
    def perturbation(self) -> Perturbation:
        return self._perturbation

    def set_perturbation(self, perturbation: Perturbation | None) -> None:
        """Use `perturbation` from the next reset on."""
        self._perturbation = perturbation or Perturbation()

    @property
    def raw_obs(self) -> np.ndarray:
        """Meta-World's flat 39-d observation of the current state (for scripted experts)."""
        return self._raw_obs

    @property
    def unwrapped_metaworld(self) -> Any:
        return self._mw

    # ----- gymnasium API ----------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        """Start setup `seed` (default: the one after the last). options: {"perturbation": Perturbation}."""
        super().reset(seed=seed)
        if options and "perturbation" in options:
            self.set_perturbation(options["perturbation"])
        setup = self._next_seed if seed is None else int(seed)
        self._select_setup(setup)
        self._setup_seed = setup
        self._next_seed = setup + 1
        self._raw_obs, _ = self._mw.reset()
        self._steps = 0
        self._noise_rng = np.random.default_rng([self.noise_seed, setup])
        if self._renderer is not None:
            self._mirror.sync_model()
            self._perturbation.lighting.apply(self._mirror.visual_model, self._base_lights)
        obs = self._observation()
        info = self._info(success=False, extra={})
        return obs, info

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (len(ACTION_LAYOUT),) or not np.isfinite(a).all():
            raise ValueError(f"action must be 4 finite numbers (dx, dy, dz, grip), got {action!r}")
        if self._steps >= self.max_steps:
            raise RuntimeError(f"episode is over ({self.max_steps} steps); call reset()")
        raw, reward, _, _, mw_info = self._mw.step(np.clip(a, -1.0, 1.0).astype(np.float32))
        self._raw_obs = raw
        self._steps += 1
        success = bool(mw_info.get("success", False))
        terminated = success and self.terminate_on_success
        truncated = self._steps >= self.max_steps
        obs = self._observation()
        return obs, float(reward), terminated, truncated, self._info(success, mw_info)

    def render(self) -> np.ndarray | None:
        if self.render_mode is None or not self.cameras or self._last_obs is None:
            return None
        return self._last_obs["images"][self.cameras[0]]

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if getattr(self, "_mw", None) is not None:
            self._mw.close()

    # ----- observations -----------------------------------------------------------------------------------
    def _observation(self) -> dict[str, Any]:
        raw = self._raw_obs
        state = np.array([raw[0], raw[1], raw[2], raw[3]], dtype=np.float32)
        images = self.render_images()
        obs = {"images": images, "state": state, "instruction": self.instruction}
        self._last_obs = obs
        return obs

    def render_images(self) -> dict[str, np.ndarray]:
        """Render every camera in the current state (sensor noise included)."""
        if self._renderer is None:
            return {}
        vd = self._mirror.sync_data(self._mw.data)
        noise = self._perturbation.noise
        out = {}
        for cam in self.cameras:
            img = self._geometry[cam].orient(self._renderer.render(vd, self._cam_ids[cam]))
            out[cam] = img if noise.is_identity else noise.apply(img, self._noise_rng)
        return out

    def _info(self, success: bool, extra: dict[str, Any]) -> dict[str, Any]:
        contact, grasp = self.contact_state()
        pts = self.key_points()
        info = {k: float(v) for k, v in extra.items() if np.isscalar(v) and k != "success"}
        info.update(
            success=success,
            raw_obs=self._raw_obs,
            setup_seed=self._setup_seed,
            steps=self._steps,
            contact=contact,
            grasp=grasp,
            **{f"{k}_pos": v for k, v in pts.items()},
        )
        return info

    # ----- privileged facts (for demonstrations and gaze) -------------------------------------------------
    def key_points(self) -> dict[str, np.ndarray]:
        """World positions (3,) of the main object `obj` (and `obj2` for two-object tasks), the task's goal
        `goal` and the gripper `hand` (the point between the finger pads)."""
        objs = np.asarray(self._mw._get_pos_objects(), dtype=np.float64)
        out = {"obj": objs[:3].copy(), "goal": np.asarray(self._mw._target_pos, dtype=np.float64).copy()}
        if objs.size >= 6:
            out["obj2"] = objs[3:6].copy()
        out["hand"] = np.asarray(self._mw.tcp_center, dtype=np.float64).copy()
        return out

    def contact_state(self) -> tuple[bool, bool]:
        """(contact, grasp): a gripper geom touches a movable non-robot body; both fingers touch one."""
        d = self._mw.data
        n = int(d.ncon)
        if n == 0:
            return False, False
        g1, g2 = np.asarray(d.contact.geom1[:n]), np.asarray(d.contact.geom2[:n])
        touching = np.asarray(d.contact.dist[:n]) <= 1e-3
        obj1, obj2 = np.isin(g1, self._object_geoms), np.isin(g2, self._object_geoms)

        def touches(geoms: np.ndarray) -> bool:
            return bool(np.any(touching & ((np.isin(g1, geoms) & obj2) | (np.isin(g2, geoms) & obj1))))

        contact = touches(self._grip_geoms)
        grasp = contact and touches(self._left_geoms) and touches(self._right_geoms)
        return contact, grasp

    def camera_geometry(self, camera: str) -> CameraGeometry:
        if camera not in self._geometry:
            raise KeyError(f"camera {camera!r} is not rendered by this env; cameras: {self.cameras}")
        return self._geometry[camera]

    def project(self, points: np.ndarray, camera: str) -> np.ndarray:
        """World points (..., 3) -> normalised (u, v) (..., 2) in `camera`'s image as the policy sees it."""
        geo = self.camera_geometry(camera)
        vd = self._mirror.visual_data
        cid = self._cam_ids[camera]
        return geo.project(points, vd.cam_xpos[cid], vd.cam_xmat[cid])


def register_gym_env() -> None:
    """Register `gazereg/MetaWorld-v0` with gymnasium (idempotent): gym.make("gazereg/MetaWorld-v0", task=...)."""
    if "gazereg/MetaWorld-v0" not in gym.registry:
        gym.register(id="gazereg/MetaWorld-v0", entry_point="gazereg.envs.metaworld.env:MetaWorldEnv")


register_gym_env()
