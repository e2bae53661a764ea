"""LIBERO-Object in the simulator: the facts its expert and the gaze read, and the expert putting an item into the
basket (needs the LIBERO venv: `bash scripts/libero_env.sh pytest -m slow tests/envs/test_libero_object_sim.py`;
skipped where hf-libero / robosuite / the assets packages are missing; the pure logic:
tests/envs/test_libero_object.py)."""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = [pytest.mark.slow, pytest.mark.libero]


@pytest.fixture(scope="module")
def env():
    from gazereg.envs.libero.env import LiberoEnv

    e = LiberoEnv("libero_object/1", cameras=("agentview",), image_size=64, max_steps=220)
    yield e
    e.close()


def test_the_item_the_basket_and_the_obstacles(env):
    """The facts the expert and the visuomotor gaze read: obj the item, goal the basket's region (inside the
    basket, in view), the basket among the obstacles, the other items too."""
    obs, info = env.reset(seed=3)
    assert env.roles.obj == "cream_cheese_1" and env.roles.goal == "basket_1_contain_region"
    assert env.roles.relation == "in" and env.scene_facts.owner(env.roles.goal) == "basket_1"
    basket = env.scene_facts.geom_boxes("basket_1")
    lo, hi = basket.corners().min(axis=0), basket.corners().max(axis=0)
    assert np.all(lo[:2] < info["goal_pos"][:2]) and np.all(info["goal_pos"][:2] < hi[:2])
    obstacles = env.scene_facts.obstacles()
    assert obstacles.top().max() == pytest.approx(hi[2])  # the basket's walls are the tallest here
    assert len(obstacles) > len(basket)  # the other items
    uv = env.project(np.stack([info["obj_pos"], info["goal_pos"]]), "agentview")
    assert ((uv > 0) & (uv < 1)).all(), uv
    assert obs["instruction"] == "pick up the cream cheese and place it in the basket"


def test_the_expert_puts_the_item_into_the_basket(env):
    """The suite's expert (`make_expert`) on one setup: a grasp of the item, then LIBERO's `In` goal within
    LIBERO-Spatial's episode length (the collector's default)."""
    from gazereg.envs.libero.collector import make_expert

    env.reset(seed=1)
    ex = make_expert(env.suite, noise=0.05)
    ex.reset(env, noise_seed=[1, 7])
    grasped, info = False, {}
    for _ in range(220):
        a = ex(env)
        assert a.shape == (7,) and a.dtype == np.float32 and np.all(np.abs(a) <= 1)
        _, _, terminated, _, info = env.step(a)
        grasped |= info["grasp"]
        if terminated:
            break
    assert info["success"] and grasped, (ex.phase, info)
    assert ex.grasp_choice["width"] < ex.p.max_width


def test_collect_expands_the_object_suite():
    from gazereg.envs.libero.collector import LiberoCollector

    assert LiberoCollector().tasks(("libero_object",)) == tuple(f"libero_object/{k}" for k in range(10))
    # every suite has an expert now, LIBERO-10's too
    assert LiberoCollector().tasks(("libero_10/0",)) == ("libero_10/0",)
