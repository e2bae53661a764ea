"""`AlohaEnv`: gym-aloha's setups, reward and action mapping behind gazereg's Env API, rendered from `top`."""

from __future__ import annotations

import numpy as np
import pytest

from gazereg.envs.aloha.env import ACTION_LAYOUT, AlohaEnv
from gazereg.envs.aloha.setup import EPISODE_LENGTH, TASKS, resolve_task
from gazereg.envs.base import make_collector


@pytest.fixture(scope="module")
def cube_env():
    env = AlohaEnv("AlohaTransferCube-v0", image_size=(96, 128))
    yield env
    env.close()


def test_setups_are_gym_alohas_own(cube_env):
    """Setup s places the cube where gym-aloha's reset(seed=s) does (its sampler), the same on every reset."""
    from gym_aloha.utils import sample_box_pose

    _, info = cube_env.reset(seed=7)
    assert np.allclose(info["obj_pos"], sample_box_pose(7)[:3], atol=1e-6)
    _, again = cube_env.reset(seed=7)
    assert np.array_equal(info["obj_pos"], again["obj_pos"])
    _, other = cube_env.reset(seed=8)
    assert not np.allclose(info["obj_pos"], other["obj_pos"])


def test_names_and_sizes_follow_lerobots_aloha_env(cube_env):
    obs, info = cube_env.reset(seed=0)
    assert set(TASKS) == {"AlohaTransferCube-v0", "AlohaInsertion-v0"}
    assert resolve_task("gym_aloha/AlohaInsertion-v0").gym_task == "insertion"
    assert cube_env.max_steps == EPISODE_LENGTH == 400 and cube_env.fps == 50
    assert obs["images"]["top"].shape == (96, 128, 3) and obs["images"]["top"].dtype == np.uint8
    assert obs["state"].shape == (14,) and len(ACTION_LAYOUT) == 14
    assert obs["instruction"] == "transfer the cube to the other arm"
    assert (
        make_collector("aloha").instruction("AlohaTransferCube-v0") == obs["instruction"]
    )  # known without a rollout
    assert info["success"] is False and info["reward"] == 0.0


def test_the_cube_projects_onto_its_red_pixels(cube_env):
    """`project` puts the cube's centre on the red blob of the top image (within 3 px at 128 px)."""
    obs, info = cube_env.reset(seed=3)
    for _ in range(10):  # let the cube fall onto the table
        obs, *_, info = cube_env.step(obs["state"])
    img = obs["images"]["top"].astype(int)
    red = (img[..., 0] > 120) & (img[..., 1] < 60) & (img[..., 2] < 60)
    rows, cols = np.nonzero(red)
    assert len(rows) > 3
    u, v = cube_env.project(info["obj_pos"], "top")
    assert abs(u * 128 - (cols.mean() + 0.5)) < 3 and abs(v * 96 - (rows.mean() + 0.5)) < 3


def test_holding_still_earns_nothing_and_bad_actions_are_refused(cube_env):
    obs, _ = cube_env.reset(seed=0)
    for _ in range(5):
        obs, reward, terminated, truncated, info = cube_env.step(obs["state"])
    assert reward == 0.0 and not terminated and not truncated and not info["contact"]
    with pytest.raises(ValueError, match="14 finite numbers"):
        cube_env.step(np.zeros(13))
    with pytest.raises(ValueError, match="14 finite numbers"):
        cube_env.step(np.full(14, np.nan))


def test_insertion_reports_both_objects_and_the_meeting_point():
    env = AlohaEnv("AlohaInsertion-v0", cameras=())
    _, info = env.reset(seed=0)
    from gym_aloha.utils import sample_insertion_pose

    peg, socket = sample_insertion_pose(0)
    assert np.allclose(info["obj_pos"], peg[:3]) and np.allclose(info["obj2_pos"], socket[:3])
    assert np.allclose(info["goal_pos"], TASKS["AlohaInsertion-v0"].meet)
    assert info["contact.obj"] is False and info["contact.obj2"] is False
    env.close()
