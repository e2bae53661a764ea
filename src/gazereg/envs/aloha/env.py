"""Gym-Aloha's bimanual ALOHA tasks (transfer cube, insertion) behind gazereg's `Env` API.

    env = AlohaEnv("AlohaTransferCube-v0", cameras=("top",), image_size=(96, 128))
    obs, info = env.reset(seed=3)        # gym-aloha's setup 3: the cube where gym_aloha's reset(seed=3) puts it
    obs["images"]["top"]                 # uint8 (96, 128, 3), top row first, as gym-aloha renders `top`
    obs["state"]                         # float32 (14,): gym-aloha's agent_pos (STATE_LAYOUT)
    obs["instruction"]                   # "transfer the cube to the other arm"
    obs, reward, terminated, truncated, info = env.step(action)   # action float32 (14,): ACTION_LAYOUT
    info["success"]                      # reward == 4 (gym-aloha's `is_success`)

Physics, reward and action mapping are gym-aloha's own (its model files and its `TransferCubeTask` /
`InsertionTask`, stepped by dm-control at 50 Hz), so a policy sees what LeRobot's `aloha` env gives it; only the
rendering is gazereg's: gym-aloha renders three 480x640 cameras at every step, here only the asked cameras are
rendered, at the asked size, with `gazereg.envs.render.FastRenderer` (no shadows, no multisampling). Nothing in
gazereg imports this module at import time; it needs the Aloha lane's venv (scripts/aloha_lane.sh).

Actions (14,): per arm (left, then right) six absolute joint positions (radians) and the gripper's normalised
opening (0 closed, 1 open), gym-aloha's action; MuJoCo clamps each to its actuator's range.
State (14,): the same layout, measured (gym-aloha's `agent_pos`).

Setups. `reset(seed=s)` places the objects with gym-aloha's sampler for seed `s` (`setup.sample_setup`), the
arms at gym-aloha's start pose.

`info` after reset and every step: success, reward, setup_seed, steps, contact and grasp (the right gripper
touches / both its fingers touch the task's first object), `contact.obj` (the right gripper touches obj: the
cube, the peg), `contact.obj2` (insertion: the left gripper touches the socket), world positions (metres)
obj_pos, obj2_pos (insertion), goal_pos (the task's meeting point `AlohaTask.meet`), hand_pos (the right
gripper's grasp point), left_hand_pos, right_hand_pos.

Perturbations: `Perturbation.lighting` on the model's lights (they only shade rendering), `Perturbation.noise`
on each image with a generator seeded by (noise_seed, setup seed), as in the other simulators.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from gazereg.envs.aloha.setup import (
    EPISODE_LENGTH,
    FPS,
    MAX_REWARD,
    AlohaUnavailable,
    aloha_available,
    resolve_task,
    sample_setup,
)
from gazereg.envs.camera import CameraGeometry
from gazereg.envs.interface import check_cameras, check_render_mode, image_hw
from gazereg.envs.perturbations import LightState, Perturbation
from gazereg.envs.render import FastRenderer, select_gl_backend
from gazereg.envs.spaces import env_spaces

ARMS = ("left", "right")
ARM_JOINTS = ("waist", "shoulder", "elbow", "forearm_roll", "wrist_angle", "wrist_rotate")
ACTION_LAYOUT = tuple(f"{a}_{j}" for a in ARMS for j in (*ARM_JOINTS, "gripper"))
STATE_LAYOUT = ACTION_LAYOUT
GRASP_POINT = np.array([0.135, 0.0, 0.0])
"""the grasp point between the finger pads in each `gripper_link` frame (metres; x points out of the gripper)"""


def finger_geoms(arm: str) -> tuple[str, str]:
    return (f"vx300s_{arm}/10_left_gripper_finger", f"vx300s_{arm}/10_right_gripper_finger")


def _import_dm_control(gl_backend: str | None) -> Any:
    ok, why = aloha_available()
    if not ok:
        raise AlohaUnavailable(why)
    # dm-control picks its (unused here) GL backend from MUJOCO_GL when first imported; without one it tries
    # GLFW and warns about a missing display.
    if gl_backend and "MUJOCO_GL" not in os.environ:
        os.environ["MUJOCO_GL"] = gl_backend
    from dm_control import mujoco as dm_mujoco

    return dm_mujoco


class AlohaEnv(gym.Env):
    """A Gym-Aloha task with RGB cameras, 14-d joint state and its instruction (see the module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": FPS}

    def __init__(
        self,
        task: str = "AlohaTransferCube-v0",
        cameras: Sequence[str] = ("top",),
        image_size: int | tuple[int, int] = (480, 640),
        seed: int = 0,
        max_steps: int | None = None,
        terminate_on_success: bool = True,
        perturbation: Perturbation | None = None,
        noise_seed: int = 0,
        gl_backend: str | None = None,
        instruction: str | None = None,
        render_mode: str | None = "rgb_array",
    ):
        spec = resolve_task(task)
        check_render_mode(render_mode)
        H, W = image_hw(image_size)
        max_steps = EPISODE_LENGTH if max_steps is None else int(max_steps)
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps}")
        self.spec_task = spec
        self.task = spec.name
        self.cameras = check_cameras(cameras)
        self.image_size = (H, W)
        self.max_steps = max_steps
        self.fps = FPS
        self.terminate_on_success = bool(terminate_on_success)
        self.noise_seed = int(noise_seed)
        self.render_mode = render_mode
        self.instruction = instruction or spec.instruction
        self._perturbation = perturbation or Perturbation()
        self.gl_backend = (gl_backend or select_gl_backend()) if self.cameras else None
        dm_mujoco = _import_dm_control(self.gl_backend)
        import mujoco
        from gym_aloha.constants import ASSETS_DIR, DT
        from gym_aloha.tasks.sim import InsertionTask, TransferCubeTask

        self._mj = mujoco
        self.physics = dm_mujoco.Physics.from_xml_path(str(ASSETS_DIR / spec.xml))
        self._n_sub = round(DT / self.physics.model.ptr.opt.timestep)
        base = TransferCubeTask if spec.gym_task == "transfer_cube" else InsertionTask
        self._task = base(random=np.random.RandomState(seed))
        self._ids()
        self.observation_space, _ = env_spaces(self.cameras, H, W, len(STATE_LAYOUT), len(ACTION_LAYOUT))
        lo, hi = self._action_bounds()
        self.action_space = gym.spaces.Box(lo, hi, dtype=np.float32)
        self._renderer: FastRenderer | None = None
        self._cam_ids: dict[str, int] = {}
        self._geometry: dict[str, CameraGeometry] = {}
        if self.cameras:
            self._make_renderer(H, W)
        self._setup_seed = int(seed)
        self._next_seed = int(seed)
        self._steps = 0
        self._reward = 0.0
        self._noise_rng = np.random.default_rng([self.noise_seed, self._setup_seed])

    def _make_renderer(self, H: int, W: int) -> None:
        """The offscreen renderer for `self.cameras` at H x W and their camera ids; the lights as loaded."""
        m, mj = self.physics_model, self._mj
        self._base_lights = LightState.capture(m)
        self._renderer = FastRenderer(m, H, W, backend=self.gl_backend)
        for c in self.cameras:
            cid = mj.mj_name2id(m, mj.mjtObj.mjOBJ_CAMERA, c)
            if cid < 0:
                names = [m.camera(i).name for i in range(m.ncam)]
                raise KeyError(f"no camera {c!r} in Gym-Aloha's model; cameras: {names}")
            self._cam_ids[c] = cid

    # ----- model facts ------------------------------------------------------------------------------------
    def _ids(self) -> None:
        m = self.physics_model
        mj = self._mj
        self._gripper_body = {
            a: mj.mj_name2id(m, mj.mjtObj.mjOBJ_BODY, f"vx300s_{a}/gripper_link") for a in ARMS
        }
        self._fingers = {
            a: {mj.mj_name2id(m, mj.mjtObj.mjOBJ_GEOM, g) for g in finger_geoms(a)} for a in ARMS
        }
        self._obj_body = [mj.mj_name2id(m, mj.mjtObj.mjOBJ_BODY, b) for b in self.spec_task.objects]
        self._obj_geoms = [{g for g in range(m.ngeom) if m.geom_bodyid[g] == b} for b in self._obj_body]

    def _action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        m = self.physics_model
        lo, hi = [], []
        for a in ARMS:
            for j in ARM_JOINTS:
                aid = self._mj.mj_name2id(m, self._mj.mjtObj.mjOBJ_ACTUATOR, f"vx300s_{a}/{j}")
                r = m.actuator_ctrlrange[aid] if aid >= 0 else m.jnt_range[m.joint(f"vx300s_{a}/{j}").id]
                lo.append(r[0])
                hi.append(r[1])
            lo.append(0.0)
            hi.append(1.0)
        return np.asarray(lo, np.float32), np.asarray(hi, np.float32)

    @property
    def physics_model(self) -> Any:
        """The raw `mujoco.MjModel` (dm-control's `physics.model.ptr`)."""
        return self.physics.model.ptr

    @property
    def physics_data(self) -> Any:
        return self.physics.data.ptr

    @property
    def setup_seed(self) -> int:
        return self._setup_seed

    @property
    def perturbation(self) -> Perturbation:
        return self._perturbation

    def set_perturbation(self, perturbation: Perturbation | None) -> None:
        """Use `perturbation` from the next reset on."""
        self._perturbation = perturbation or Perturbation()

    # ----- gymnasium API ----------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        """Start setup `seed` (default: the one after the last). options: {"perturbation": Perturbation}."""
        super().reset(seed=seed)
        if options and "perturbation" in options:
            self.set_perturbation(options["perturbation"])
        from gym_aloha.tasks import sim

        setup = self._next_seed if seed is None else int(seed)
        self._setup_seed, self._next_seed = setup, setup + 1
        sim.BOX_POSE[0] = sample_setup(self.spec_task, setup)  # gym-aloha's tasks read their poses from here
        with self.physics.reset_context():
            self._task.initialize_episode(self.physics)
        self._steps = 0
        self._reward = float(self._task.get_reward(self.physics))
        self._noise_rng = np.random.default_rng([self.noise_seed, setup])
        if self._renderer is not None:
            self._perturbation.lighting.apply(self.physics_model, self._base_lights)
        return self._observation(), self._info()

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (len(ACTION_LAYOUT),) or not np.isfinite(a).all():
            raise ValueError(f"action must be 14 finite numbers {ACTION_LAYOUT}, got {action!r}")
        if self._steps >= self.max_steps:
            raise RuntimeError(f"episode is over ({self.max_steps} steps); call reset()")
        self._task.before_step(a, self.physics)  # gym-aloha's mapping: grippers unnormalised, ctrl set
        self.physics.step(self._n_sub)
        self._task.after_step(self.physics)
        self._steps += 1
        self._reward = float(self._task.get_reward(self.physics))
        info = self._info()
        terminated = info["success"] and self.terminate_on_success
        truncated = self._steps >= self.max_steps
        return self._observation(), self._reward, terminated, truncated, info

    def render(self) -> np.ndarray | None:
        if self.render_mode is None or not self.cameras:
            return None
        return self.render_images()[self.cameras[0]]

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # ----- observations -----------------------------------------------------------------------------------
    def state(self) -> np.ndarray:
        """gym-aloha's agent_pos (14,): joint positions and normalised gripper openings."""
        return np.asarray(self._task.get_qpos(self.physics), dtype=np.float32)

    def _observation(self) -> dict[str, Any]:
        return {"images": self.render_images(), "state": self.state(), "instruction": self.instruction}

    def render_images(self) -> dict[str, np.ndarray]:
        """Every camera in the current state, top row first as gym-aloha renders them (noise included)."""
        if self._renderer is None:
            return {}
        noise = self._perturbation.noise
        out = {}
        for cam in self.cameras:
            img = np.ascontiguousarray(self._renderer.render(self.physics_data, self._cam_ids[cam]))
            out[cam] = img if noise.is_identity else noise.apply(img, self._noise_rng)
        return out

    def _info(self) -> dict[str, Any]:
        touching = self._touching()
        contact, grasp = self.contact_state(touching)
        info: dict[str, Any] = {
            "success": self._reward >= MAX_REWARD,
            "reward": self._reward,
            "setup_seed": self._setup_seed,
            "steps": self._steps,
            "contact": contact,
            "grasp": grasp,
            "contact.obj": any(touching["right"][0]),
            **{f"{k}_pos": v for k, v in self.key_points().items()},
        }
        if len(self._obj_body) > 1:
            info["contact.obj2"] = any(touching["left"][1])
        return info

    # ----- privileged facts (for the expert and the gaze) -------------------------------------------------
    def grasp_point(self, arm: str) -> np.ndarray:
        """World position (3,) of `arm`'s grasp point (between its finger pads), metres."""
        b = self._gripper_body[arm]
        d = self.physics_data
        return d.xpos[b] + d.xmat[b].reshape(3, 3) @ GRASP_POINT

    def key_points(self) -> dict[str, np.ndarray]:
        """World positions (3,): obj (cube; peg), obj2 (socket), goal (the meeting point), hand (the right
        gripper, the one that takes obj), left_hand, right_hand."""
        d = self.physics_data
        pts = {("obj", "obj2")[i]: d.xpos[b].copy() for i, b in enumerate(self._obj_body)}
        pts["goal"] = np.asarray(self.spec_task.meet, dtype=np.float64)
        pts["hand"] = self.grasp_point("right")
        pts["left_hand"] = self.grasp_point("left")
        pts["right_hand"] = pts["hand"].copy()
        return pts

    def object_pose(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Position (3,) and rotation matrix (3, 3) of free object `k` (0: obj, 1: obj2)."""
        b = self._obj_body[k]
        d = self.physics_data
        return d.xpos[b].copy(), d.xmat[b].reshape(3, 3).copy()

    def _touching(self) -> dict[str, list[tuple[bool, bool]]]:
        """Per arm, per object: (its left finger touches it, its right finger touches it)."""
        d = self.physics_data
        out = {a: [[False, False] for _ in self._obj_geoms] for a in ARMS}
        fingers = {a: finger_geoms(a) for a in ARMS}
        m = self.physics_model
        for i in range(d.ncon):
            g1, g2 = int(d.contact[i].geom1), int(d.contact[i].geom2)
            for k, geoms in enumerate(self._obj_geoms):
                other = g2 if g1 in geoms else g1 if g2 in geoms else None
                if other is None:
                    continue
                for a in ARMS:
                    if other in self._fingers[a]:
                        out[a][k][fingers[a].index(m.geom(other).name)] = True
        return {a: [(bool(x), bool(y)) for x, y in v] for a, v in out.items()}

    def contact_state(self, touching: dict[str, list[tuple[bool, bool]]] | None = None) -> tuple[bool, bool]:
        """(contact, grasp): a finger of the right gripper touches obj (cube, peg); both of its fingers do."""
        t = (touching or self._touching())["right"][0]
        return bool(t[0] or t[1]), bool(t[0] and t[1])

    # ----- geometry ---------------------------------------------------------------------------------------
    def camera_geometry(self, camera: str) -> CameraGeometry:
        """The geometry of `camera` as rendered (top row first, never turned: gym-aloha's images)."""
        if camera not in self._cam_ids:
            raise KeyError(f"camera {camera!r} is not rendered by this env; cameras: {self.cameras}")
        if camera not in self._geometry:
            H, W = self.image_size
            fovy = float(self.physics_model.cam_fovy[self._cam_ids[camera]])
            self._geometry[camera] = CameraGeometry(camera, H, W, fovy, rot180=False)
        return self._geometry[camera]

    def project(self, points: np.ndarray, camera: str) -> np.ndarray:
        """World points (..., 3) -> normalised (u right, v down) (..., 2) in `camera`'s image."""
        geo = self.camera_geometry(camera)
        cid = self._cam_ids[camera]
        d = self.physics_data
        return geo.project(points, d.cam_xpos[cid], d.cam_xmat[cid])
