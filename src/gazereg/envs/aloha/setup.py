"""Gym-Aloha's tasks as gazereg knows them, and the check that gym-aloha can be imported.

    TASKS["AlohaTransferCube-v0"].instruction     # "transfer the cube to the other arm"
    aloha_available()                             # (True, "") in the Aloha lane's venv (scripts/aloha_lane.sh)

Task names are LeRobot's `aloha` env names (`--env.type=aloha --env.task=AlohaTransferCube-v0`, registered by
gym-aloha as `gym_aloha/AlohaTransferCube-v0`), the camera is `top` (LeRobot's `observation.images.top`), and
an episode lasts `EPISODE_LENGTH` steps at `FPS` frames per second (LeRobot's `AlohaEnv` config: 400 at 50).
Nothing here imports gym-aloha, dm-control or MuJoCo.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass

import numpy as np

EPISODE_LENGTH = 400
"""steps per episode in LeRobot's `aloha` env config (gym-aloha's own registration says 300)"""
FPS = 50.0
"""control steps per second (gym-aloha's DT = 0.02 s: 10 physics steps of 2 ms)"""
MAX_REWARD = 4
"""both tasks' top reward: success (transfer: the left gripper holds the cube off the table; insertion: the peg
touches the pin inside the socket)"""
CAMERAS = ("top",)
"""the camera LeRobot's `aloha` env observes (`observation.images.top`); gym-aloha's model also has `angle`,
`front_close`, `left_pillar`, `right_pillar`, `left_wrist` and `right_wrist`, which render here too"""


@dataclass(frozen=True)
class AlohaTask:
    """One Gym-Aloha task: its gym-aloha name, model file, instruction, and the points the expert and the
    gaze use (world metres): `meet` is where the two hands meet (the hand-over point; where the socket is held
    for the insertion)."""

    name: str
    gym_task: str
    xml: str
    instruction: str
    meet: tuple[float, float, float]
    objects: tuple[str, ...]
    """the free bodies' names: obj (the cube; the peg), then obj2 (the socket)"""


TASKS: dict[str, AlohaTask] = {
    "AlohaTransferCube-v0": AlohaTask(
        name="AlohaTransferCube-v0",
        gym_task="transfer_cube",
        xml="bimanual_viperx_transfer_cube.xml",
        instruction="transfer the cube to the other arm",
        meet=(0.0, 0.5, 0.25),
        objects=("box",),
    ),
    "AlohaInsertion-v0": AlohaTask(
        name="AlohaInsertion-v0",
        gym_task="insertion",
        xml="bimanual_viperx_insertion.xml",
        instruction="insert the peg into the socket",
        meet=(-0.04, 0.5, 0.25),
        objects=("peg", "socket"),
    ),
}


class AlohaUnavailable(RuntimeError):
    """gym-aloha (or dm-control) cannot be imported here: run in the Aloha lane's venv."""


def aloha_available() -> tuple[bool, str]:
    """(True, "") when gym-aloha and dm-control can be imported, else (False, why) in one line."""
    missing = [m for m in ("gym_aloha", "dm_control", "mujoco") if importlib.util.find_spec(m) is None]
    if missing:
        return False, (
            f"{', '.join(missing)} not installed: Gym-Aloha runs in its own venv "
            "(bash scripts/aloha_lane.sh creates ~/.cache/gazereg/aloha-py<X.Y>)"
        )
    return True, ""


def resolve_task(name: str) -> AlohaTask:
    """The task called `name` (LeRobot's spelling; gym-aloha's `transfer_cube`/`insertion` and the
    `gym_aloha/` prefix accepted); KeyError naming the known ones."""
    key = name.removeprefix("gym_aloha/")
    for t in TASKS.values():
        if key in (t.name, t.gym_task):
            return t
    raise KeyError(f"unknown Gym-Aloha task {name!r}; tasks: {', '.join(TASKS)}")


def sample_setup(task: AlohaTask, seed: int) -> np.ndarray:
    """The free objects' initial poses of setup `seed`: gym-aloha's own sampler (`gym_aloha.utils`), the one
    `gym_aloha`'s `reset(seed=seed)` uses, so setup `s` here is LeRobot's episode with seed `s`.
    Returns (7 * number of objects,) float64: position (3) and quaternion (w, x, y, z) per object."""
    from gym_aloha.utils import sample_box_pose, sample_insertion_pose

    if task.gym_task == "transfer_cube":
        return np.asarray(sample_box_pose(seed), dtype=np.float64)
    return np.concatenate(sample_insertion_pose(seed)).astype(np.float64)
