"""A gymnasium environment over the LIBERO suites, with the same API as `gazereg.envs.metaworld.env.MetaWorldEnv`.

    env = LiberoEnv("libero_spatial", cameras=("agentview", "wrist"), image_size=128)
    obs, info = env.reset(seed=3)        # task 3 of the suite, its fixed initial state 0
    obs["images"]["agentview"]           # uint8 (128, 128, 3), upright as the episode store holds LIBERO frames
    obs["state"]                         # float32 (8,): eef x, y, z, eef axis-angle (3), gripper finger qpos (2)
    obs["instruction"]                   # "pick up the black bowl between the plate and the ramekin and ..."
    obs, reward, terminated, truncated, info = env.step(action)   # action float32 (7,) in [-1, 1]
    info["success"]                      # LIBERO's goal predicate (the task's BDDL) after this step
    info["obj_pos"], info["goal_pos"]    # world (3,): the bowl and the plate (`key_points`, see libero_scene)
    info["contact"], info["grasp"]       # the gripper touches the bowl / both fingers do

LIBERO needs its own venv (robosuite 1.4.0 with mujoco < 3.9; Meta-World pins mujoco 3.3.0): see
`scripts/libero_env.sh`. Nothing in gazereg imports this module at import time.

Tasks and seeds. `task` is a suite (`libero_spatial`, `libero_object`, `libero_goal`, `libero_10`; 10 tasks
each with 50 fixed initial states, LIBERO's `.pruned_init` files) or one task of a suite, `libero_spatial/3`
(index) or `libero_spatial/<task name>`. For a suite, setup seed `s` is task `s % 10` with initial state
`(s // 10) % 50`, so consecutive seeds cover every task; for one task, seed `s` is initial state `s % 50`; from
10,000 on, a placement LIBERO's initializer samples, seeded by the setup (validation setups: `setup_index`).
`reset(seed=s)` selects setup `s`; `reset()` without a seed takes the next one. Changing task rebuilds the
robosuite environment (a few seconds). After the initial state is set, `settle_steps` (default 10) no-op
actions (arm still, gripper open) let the objects settle, as the standard LIBERO evaluations do; they do
not count as steps.

State. `[eef_x, eef_y, eef_z, eef_ax, eef_ay, eef_az, gripper_l, gripper_r]`: robosuite's end-effector position
(world, metres), its orientation as an axis-angle vector and the two finger joint positions: LIBERO's
`ee_pos + ee_ori + gripper_states`, the default state of the HDF5 importer (`gazereg.data.formats.hdf5`).

`info` after reset and every step (as `MetaWorldEnv`'s): success, setup_seed, task_index, task_name,
init_state_index, steps, contact, grasp, and world positions (metres) obj_pos, goal_pos (when the task has a
placement goal), hand_pos (between the finger pads); `roles` names obj and goal (`gazereg.envs.libero.scene`).

Actions. LIBERO's OSC_POSE controller: (dx, dy, dz, drx, dry, drz, grip) in [-1, 1]; grip -1 opens, +1 closes.
20 control steps per second.

Images. Rendered from robosuite's own MuJoCo model/data with `gazereg.envs.render.FastRenderer` (shadows,
reflections and multisampling off, an offscreen buffer exactly the image size), not with robosuite's camera
observables. LIBERO's HDF5 frames are robosuite's raw OpenGL buffers (bottom row first); the importer turns them
by 180 degrees and the store holds them that way, so the images here are the raw buffer turned by 180 degrees
(`raw[::-1, ::-1]`) -- exactly what OpenVLA's and LeRobot's LIBERO pipelines feed a policy. Like robosuite's
cameras, only the visual geoms are drawn (the collision group is hidden). With `mesh_cell` (default "auto": 1 cm
up to 160 px, 5 mm up to 320 px, none above) the images come from a render-only copy of the model whose meshes
are simplified, textures kept (`gazereg.envs.libero.render`): about twice the steps/s with two 128 px cameras,
at a mean absolute difference of about 3 grey levels from the full meshes (`mesh_cell=None`). Relative to
MuJoCo's top-row-first camera view that is a left-right mirror; `project` accounts for it. Cameras:
`agentview` and `robot0_eye_in_hand` (aliases `wrist`, and the names `gazereg import hdf5` gives LIBERO's frames:
`agentview_rgb`, `eye_in_hand_rgb`; the returned dict uses the names asked for).

Perturbations. `Perturbation.lighting` is applied to the model's lights and headlight at every reset (lights
only shade rendering; physics never reads them) and `Perturbation.noise` to each image, with a generator
seeded by (noise_seed, setup seed) per episode, as in `MetaWorldEnv`.

LIBERO's config and import: `gazereg.envs.libero.setup`.

EGL teardown. robosuite's own renderer (the one that prints `EGLError ... eglDestroyContext` at exit when its
context outlives the EGL display) is never created here (`has_offscreen_renderer=False`); the FastRenderer
is closed by `close()`, or at exit before EGL's own atexit handler runs (see `gazereg.envs.render`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from gazereg.envs.camera import CameraGeometry, camera_geometry
from gazereg.envs.interface import check_cameras, check_render_mode, image_hw
from gazereg.envs.libero.render import (
    CAMERA_ALIASES,
    COLLISION_GROUP,
    camera_ids,
    compile_render_copy,
    sync_appearance,
)
from gazereg.envs.libero.scene import SceneFacts, TaskRoles, quat_xyzw_to_axis_angle
from gazereg.envs.libero.setup import (
    SUITE_MAX_STEPS,
    fixture_homes,
    import_libero,
    make_control_env,
    parse_task,
    reset_scene,
    resolve_task,
    setup_index,
    suite_benchmark,
)
from gazereg.envs.perturbations import LightState, Perturbation
from gazereg.envs.render import FastRenderer, VisualMirror, resolve_mesh_cell, select_gl_backend
from gazereg.envs.spaces import env_spaces

STATE_LAYOUT = ("eef_x", "eef_y", "eef_z", "eef_ax", "eef_ay", "eef_az", "gripper_l", "gripper_r")
ACTION_LAYOUT = ("dx", "dy", "dz", "drx", "dry", "drz", "grip")
NOOP_ACTION = np.array([0, 0, 0, 0, 0, 0, -1], dtype=np.float64)
CONTROL_FREQ = 20


class LiberoEnv(gym.Env):
    """A LIBERO suite (or one task of it) with RGB cameras, 8-d proprioception and its instruction."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": CONTROL_FREQ}

    def __init__(
        self,
        task: str = "libero_spatial",
        cameras: Sequence[str] = ("agentview", "robot0_eye_in_hand"),
        image_size: int | tuple[int, int] = 128,
        seed: int = 0,
        max_steps: int | None = None,
        terminate_on_success: bool = True,
        perturbation: Perturbation | None = None,
        noise_seed: int = 0,
        gl_backend: str | None = None,
        settle_steps: int = 10,
        mesh_cell: float | str | None = "auto",
        instruction: str | None = None,
        render_mode: str | None = "rgb_array",
    ):
        suite, which = parse_task(task)
        check_render_mode(render_mode)
        H, W = image_hw(image_size)
        max_steps = SUITE_MAX_STEPS[suite] if max_steps is None else int(max_steps)
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps}")
        self.cameras = check_cameras(cameras)
        self.gl_backend = (gl_backend or select_gl_backend()) if self.cameras else None
        import_libero(self.gl_backend)
        import mujoco

        self._mj = mujoco
        self.task = task
        self.suite = suite
        _, which = resolve_task(task)
        self.task_names = list(suite_benchmark(suite).get_task_names())
        self._fixed_task = which
        self.image_size = (H, W)
        self.max_steps = max_steps
        self.terminate_on_success = bool(terminate_on_success)
        self.noise_seed = int(noise_seed)
        self.settle_steps = int(settle_steps)
        self.render_mode = render_mode
        self._instruction_override = instruction
        self._perturbation = perturbation or Perturbation()
        self.mesh_cell = mesh_cell
        self._init_fields(int(seed))
        self.observation_space, self.action_space = env_spaces(
            self.cameras, H, W, len(STATE_LAYOUT), len(ACTION_LAYOUT)
        )
        self.fps = float(CONTROL_FREQ)
        self.metadata = {**self.metadata, "render_fps": self.fps}
        self._build(self.setup_of(self._setup_seed)[0])

    def _init_fields(self, seed: int) -> None:
        """The state before any task is built: setup `seed` comes next."""
        self._env: Any = None
        self._facts: SceneFacts | None = None
        self._fixture_homes: dict[int, Any] = {}
        self._task_index: int | None = None
        self._renderer: FastRenderer | None = None
        self._mirror: VisualMirror | None = None
        self._geometry: dict[str, CameraGeometry] = {}
        self._cam_ids: dict[str, int] = {}
        self._setup_seed = seed
        self._next_seed = seed
        self._init_index = 0
        self._steps = 0
        self._last_obs: dict[str, Any] | None = None
        self._rs_obs: dict[str, Any] = {}
        self._noise_rng = np.random.default_rng([self.noise_seed, self._setup_seed])

    # ----- setups -----------------------------------------------------------------------------------------
    def setup_of(self, seed: int) -> tuple[int, int]:
        """Setup seed -> (task index in the suite, initial-state index among the task's fixed ones)."""
        return setup_index(self.suite, self._fixed_task, seed)

    def _build(self, index: int) -> None:
        if self._task_index == index and self._env is not None:
            return
        self._close_env()
        bddl = suite_benchmark(self.suite).get_task_bddl_file_path(index)
        self._env = make_control_env(bddl, CONTROL_FREQ)
        self._task_index = index
        self._facts = SceneFacts(self._env.env)
        self._fixture_homes = fixture_homes(self._env.env)
        self._geometry = {}
        # The benchmark's task language (from the BDDL file name), as OpenVLA's and LeRobot's LIBERO data use;
        # the BDDL's own `(:language ...)` line sometimes differs ("Pick the akita black bowl ...").
        self.instruction = self._instruction_override or str(
            suite_benchmark(self.suite).get_task(index).language
        )
        if self.cameras:
            self._start_rendering(self.physics_model)

    def _start_rendering(self, m: Any) -> None:
        """The renderer of the current task's cameras, from a render copy with simplified meshes (`mesh_cell`)
        or from the physics model `m` itself."""
        H, W = self.image_size
        cell = resolve_mesh_cell(self.mesh_cell, H, W)
        # robosuite compiled the physics model from this XML (absolute asset paths): compile it again.
        visual = m if cell is None else compile_render_copy(self._env.env.model.get_xml(), m, cell)
        self._mirror = None if visual is m else VisualMirror(m, visual)
        self._base_lights = LightState.capture(visual)
        self._renderer = FastRenderer(visual, H, W, backend=self.gl_backend)
        # robosuite's cameras (and so LIBERO's data) show the visual geoms only: hide the collision group.
        self._renderer.option.geomgroup[COLLISION_GROUP] = 0
        self._cam_ids = camera_ids(m, self.cameras)

    def _close_env(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._env is not None:
            with contextlib.suppress(Exception):
                self._env.close()
            self._env = None
            self._task_index = None

    @property
    def physics_model(self) -> Any:
        """robosuite's raw `mujoco.MjModel` of the current task."""
        return self._env.sim.model._model

    @property
    def physics_data(self) -> Any:
        return self._env.sim.data._data

    @property
    def setup_seed(self) -> int:
        return self._setup_seed

    @property
    def task_index(self) -> int:
        return int(self._task_index)  # type: ignore[arg-type]

    @property
    def perturbation(self) -> Perturbation:
        return self._perturbation

    def set_perturbation(self, perturbation: Perturbation | None) -> None:
        """Use `perturbation` from the next reset on."""
        self._perturbation = perturbation or Perturbation()

    @property
    def unwrapped_libero(self) -> Any:
        """LIBERO's `ControlEnv` of the current task."""
        return self._env

    # ----- gymnasium API ----------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        """Start setup `seed` (default: the one after the last). options: {"perturbation": Perturbation}."""
        super().reset(seed=seed)
        if options and "perturbation" in options:
            self.set_perturbation(options["perturbation"])
        setup = self._next_seed if seed is None else int(seed)
        t, k = self.setup_of(setup)
        self._build(t)
        self._setup_seed = setup
        self._next_seed = setup + 1
        self._init_index = k
        self._rs_obs = reset_scene(self._env, self.physics_data, self.suite, (t, k), self._fixture_homes)
        for _ in range(self.settle_steps):
            self._rs_obs, _, _, _ = self._env.step(NOOP_ACTION)
        self._steps = 0
        self._noise_rng = np.random.default_rng([self.noise_seed, setup])
        if self._renderer is not None:
            if self._mirror is not None:
                self._mirror.sync_model()  # LIBERO places fixtures through the model at resets
                sync_appearance(self.physics_model, self._mirror.visual_model)
            self._perturbation.lighting.apply(self._renderer.model, self._base_lights)
        obs = self._observation()
        return obs, self._info(bool(self._env.check_success()))

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (len(ACTION_LAYOUT),) or not np.isfinite(a).all():
            raise ValueError(f"action must be 7 finite numbers {ACTION_LAYOUT}, got {action!r}")
        if self._steps >= self.max_steps:
            raise RuntimeError(f"episode is over ({self.max_steps} steps); call reset()")
        self._rs_obs, reward, _, _ = self._env.step(np.clip(a, -1.0, 1.0))
        self._steps += 1
        success = bool(self._env.check_success())
        terminated = success and self.terminate_on_success
        truncated = self._steps >= self.max_steps
        return self._observation(), float(reward), terminated, truncated, self._info(success)

    def render(self) -> np.ndarray | None:
        if self.render_mode is None or not self.cameras or self._last_obs is None:
            return None
        return self._last_obs["images"][self.cameras[0]]

    def close(self) -> None:
        self._close_env()

    # ----- observations -----------------------------------------------------------------------------------
    def state(self) -> np.ndarray:
        o = self._rs_obs
        return np.concatenate(
            [
                np.asarray(o["robot0_eef_pos"], dtype=np.float64),
                quat_xyzw_to_axis_angle(o["robot0_eef_quat"]),
                np.asarray(o["robot0_gripper_qpos"], dtype=np.float64),
            ]
        ).astype(np.float32)

    def _observation(self) -> dict[str, Any]:
        obs = {"images": self.render_images(), "state": self.state(), "instruction": self.instruction}
        self._last_obs = obs
        return obs

    def render_images(self) -> dict[str, np.ndarray]:
        """Render every camera in the current state, turned as the store holds LIBERO frames (noise included)."""
        if self._renderer is None:
            return {}
        d = self._render_data()
        noise = self._perturbation.noise
        out = {}
        for cam in self.cameras:
            # render_raw is bottom row first, as robosuite's buffers; [::-1, ::-1] is LIBERO's 180-degree turn.
            img = np.ascontiguousarray(self._renderer.render_raw(d, self._cam_ids[cam])[::-1, ::-1])
            out[cam] = img if noise.is_identity else noise.apply(img, self._noise_rng)
        return out

    def _render_data(self) -> Any:
        """The data the images are rendered from, in the current state (the render copy's, when there is one)."""
        if self._mirror is not None:
            return self._mirror.sync_data(self.physics_data)
        d = self.physics_data
        self._mj.mj_camlight(self.physics_model, d)  # robosuite's steps leave those of the last substep
        return d

    def _info(self, success: bool) -> dict[str, Any]:
        contact, grasp = self.contact_state()
        return {
            "success": success,
            "setup_seed": self._setup_seed,
            "task_index": self._task_index,
            "task_name": self.task_names[self._task_index],  # type: ignore[index]
            "init_state_index": self._init_index,
            "steps": self._steps,
            "contact": contact,
            "grasp": grasp,
            **{f"{k}_pos": v for k, v in self.key_points().items()},
        }

    # ----- privileged facts (for demonstrations and gaze) -------------------------------------------------
    @property
    def roles(self) -> TaskRoles:
        """The BDDL names of the task's object (`obj`) and of where it must go (`goal`): see libero_scene."""
        return self._facts.roles  # type: ignore[union-attr]

    @property
    def scene_facts(self) -> SceneFacts:
        """The current task's `SceneFacts` (positions, obstacle boxes, contact)."""
        return self._facts  # type: ignore[return-value]

    def key_points(self) -> dict[str, np.ndarray]:
        """World positions (3,) of the task's object `obj` (LIBERO-Spatial: the black bowl), its goal `goal`
        (the plate; absent for tasks without a placement goal) and the gripper `hand` (between the finger pads)."""
        return self._facts.key_points()  # type: ignore[union-attr]

    def contact_state(self) -> tuple[bool, bool]:
        """(contact, grasp): a gripper geom touches obj; geoms of both fingers touch it."""
        return self._facts.contact_state()  # type: ignore[union-attr]

    # ----- geometry ---------------------------------------------------------------------------------------
    def camera_geometry(self, camera: str) -> CameraGeometry:
        """MuJoCo's top-row-first geometry of `camera` (the returned images are this view mirrored left-right)."""
        if camera not in self._cam_ids:
            raise KeyError(f"camera {camera!r} is not rendered by this env; cameras: {self.cameras}")
        if camera not in self._geometry:
            H, W = self.image_size
            name = CAMERA_ALIASES.get(camera, camera)
            geo = camera_geometry(self.physics_model, self.physics_data, name, H, W)
            # Orientation here is fixed by LIBERO's convention, not by the camera's up axis.
            self._geometry[camera] = CameraGeometry(
                geo.name, geo.height, geo.width, geo.fovy_deg, rot180=False
            )
        return self._geometry[camera]

    def project(self, points: np.ndarray, camera: str) -> np.ndarray:
        """World points (..., 3) -> normalised (u, v) (..., 2) in `camera`'s image as returned (mirrored u)."""
        geo = self.camera_geometry(camera)
        d = self._mirror.visual_data if self._mirror is not None else self.physics_data
        cid = self._cam_ids[camera]
        uv = geo.project(points, d.cam_xpos[cid], d.cam_xmat[cid])
        uv[..., 0] = 1.0 - uv[..., 0]
        return uv
