"""The gymnasium wrapper: spaces, observations, seeds -> setups, success, determinism."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def env(gl_backend):
    from gazereg.envs import MetaWorldEnv

    e = MetaWorldEnv(
        "pick-place-v3", cameras=("corner2", "topview"), image_size=(64, 80), gl_backend=gl_backend
    )
    yield e
    e.close()


def test_observation_matches_its_space(env):
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert set(obs["images"]) == {"corner2", "topview"}
    for img in obs["images"].values():
        assert img.dtype == np.uint8 and img.shape == (64, 80, 3)
    assert obs["state"].dtype == np.float32 and obs["state"].shape == (4,)
    assert obs["instruction"] == "Pick up the puck and place it at the goal."
    assert env.action_space.shape == (4,)
    assert info["success"] is False and info["setup_seed"] == 0
    assert {"raw_obs", "obj_pos", "goal_pos", "hand_pos", "contact", "grasp"} <= set(info)


def test_state_is_hand_position_and_gripper_opening(env):
    obs, _ = env.reset(seed=0)
    mw = env.unwrapped_metaworld
    np.testing.assert_allclose(obs["state"][:3], mw.get_endeff_pos(), atol=1e-6)
    assert 0.0 <= obs["state"][3] <= 1.0
    opened = obs["state"][3]
    for _ in range(15):
        obs, *_ = env.step(np.array([0, 0, 0, 1.0], dtype=np.float32))  # close the gripper
    assert obs["state"][3] < opened - 0.2


def test_seeds_fix_setups_as_metaworld_mt1_does(env):
    import metaworld

    from gazereg.envs import setup_of

    assert (
        setup_of(0) == (0, 0)
        and setup_of(49) == (0, 49)
        and setup_of(50) == (1, 0)
        and setup_of(123) == (2, 23)
    )
    _, a = env.reset(seed=5)
    _, b = env.reset(seed=6)
    _, c = env.reset(seed=5)
    assert not np.allclose(a["obj_pos"], b["obj_pos"]) or not np.allclose(a["goal_pos"], b["goal_pos"])
    np.testing.assert_array_equal(a["obj_pos"], c["obj_pos"])
    np.testing.assert_array_equal(a["goal_pos"], c["goal_pos"])
    # Setup 5 is Meta-World's own MT1(seed=0) setup 5.
    mt1 = metaworld.MT1("pick-place-v3", seed=0)
    ref = metaworld.env_dict.ALL_V3_ENVIRONMENTS["pick-place-v3"]()
    ref.set_task(mt1.train_tasks[5])
    ref.reset()
    np.testing.assert_allclose(ref._target_pos, a["goal_pos"])
    np.testing.assert_allclose(ref._get_pos_objects()[:3], a["obj_pos"], atol=1e-6)
    # reset() without a seed moves on to the next setup
    env.reset(seed=7)
    _, nxt = env.reset()
    assert nxt["setup_seed"] == 8


def test_same_seed_same_images(env):
    o1, _ = env.reset(seed=2)
    kept = {cam: img.copy() for cam, img in o1["images"].items()}
    o2, _ = env.reset(seed=2)
    for cam in env.cameras:
        np.testing.assert_array_equal(o1["images"][cam], o2["images"][cam])
    for _ in range(5):
        o3, *_ = env.step(np.array([1.0, 0, 0, 0], dtype=np.float32))
    for cam in env.cameras:  # observations are copies: later renders do not change them
        np.testing.assert_array_equal(o1["images"][cam], kept[cam])
        assert o1["images"][cam].flags.c_contiguous
    assert not np.array_equal(o3["images"]["corner2"], kept["corner2"])


def test_expert_succeeds_and_the_env_says_so(gl_backend):
    from gazereg.envs import Expert, MetaWorldEnv

    env = MetaWorldEnv("reach-v3", cameras=(), max_steps=150, gl_backend=gl_backend)
    obs, info = env.reset(seed=0)
    assert obs["images"] == {}
    expert = Expert("reach-v3")
    for _ in range(150):
        obs, reward, terminated, truncated, info = env.step(expert(env.raw_obs))
        if terminated or truncated:
            break
    assert terminated and info["success"] and not truncated
    assert np.linalg.norm(info["hand_pos"] - info["goal_pos"]) < 0.06
    env.close()


def test_truncation_and_bad_actions(gl_backend):
    from gazereg.envs import MetaWorldEnv

    env = MetaWorldEnv("push-v3", cameras=(), max_steps=3, gl_backend=gl_backend)
    env.reset(seed=0)
    zero = np.zeros(4, dtype=np.float32)
    assert env.step(zero)[3] is False
    env.step(zero)
    assert env.step(zero)[3] is True
    with pytest.raises(RuntimeError, match="reset"):
        env.step(zero)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="4 finite"):
        env.step(np.array([np.nan, 0, 0, 0]))
    with pytest.raises(KeyError, match="unknown Meta-World task"):
        MetaWorldEnv("fly-v3", cameras=())
    env.close()


def test_gymnasium_registration(gl_backend):
    import gazereg.envs.metaworld.env  # noqa: F401  (registers the id)

    env = gym.make(
        "gazereg/MetaWorld-v0", task="reach-v3", cameras=("corner2",), image_size=32, gl_backend=gl_backend
    )
    obs, _ = env.reset(seed=1)
    assert obs["images"]["corner2"].shape == (32, 32, 3)
    assert env.render().shape == (32, 32, 3)
    env.close()


def test_instructions_cover_the_tasks():
    from gazereg.envs.metaworld.env import meta_world_tasks
    from gazereg.envs.metaworld.instructions import INSTRUCTIONS, instruction_for

    tasks = meta_world_tasks()
    assert set(tasks) <= set(INSTRUCTIONS)
    for t in (
        "reach-v3",
        "push-v3",
        "pick-place-v3",
        "button-press-topdown-v3",
        "drawer-open-v3",
        "door-open-v3",
        "window-open-v3",
    ):
        assert instruction_for(t).endswith(".") and len(instruction_for(t).split()) >= 3
    assert instruction_for("stack-blocks-v9") == "Perform the task: stack blocks."
