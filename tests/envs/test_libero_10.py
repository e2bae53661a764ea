"""LIBERO-10's expert: the steps a conjunction of goal predicates becomes (no LIBERO needed), a mug's cup and
handle from its boxes, and, in the LIBERO venv (slow: `bash scripts/libero_env.sh pytest -m slow
tests/envs/test_libero_10.py`, a few minutes), a plan for every task and two tasks solved, one of them with a
collected episode's gaze parts. Its success per task: docs/benchmarks/libero_10_expert.json."""

from __future__ import annotations

import numpy as np
import pytest

from gazereg.envs.libero.collector import EXPERTS, make_expert
from gazereg.envs.libero.expert_10 import LongExpert, Step, plan_steps, spread_offsets
from gazereg.envs.libero.long_placers import cup_geometry
from gazereg.envs.libero.scene import Boxes

# LIBERO-10's goals as `goal_predicates` reads them from the BDDL files, in the suite's task order.
GOALS = {
    "soup_and_sauce_in_basket": [
        ["in", "alphabet_soup_1", "basket_1_contain_region"],
        ["in", "tomato_sauce_1", "basket_1_contain_region"],
    ],
    "stove_and_moka": [["turnon", "flat_stove_1"], ["on", "moka_pot_1", "flat_stove_1_cook_region"]],
    "bowl_in_drawer_and_close": [
        ["close", "white_cabinet_1_bottom_region"],
        ["in", "akita_black_bowl_1", "white_cabinet_1_bottom_region"],
    ],
    "two_moka_pots": [
        ["on", "moka_pot_1", "flat_stove_1_cook_region"],
        ["on", "moka_pot_2", "flat_stove_1_cook_region"],
        ["turnon", "flat_stove_1"],
    ],
    "mug_in_microwave": [
        ["in", "white_yellow_mug_1", "microwave_1_heating_region"],
        ["close", "microwave_1"],
    ],
}


def test_libero_10_has_an_expert():
    assert EXPERTS["libero_10"] is LongExpert
    ex = make_expert("libero_10", 0.1)
    assert isinstance(ex, LongExpert) and ex.noise == 0.1


def test_a_conjunction_becomes_steps_in_a_sensible_order():
    """Knobs first (nothing stands in the way yet), placements in the BDDL's order, closing last."""
    kinds = {name: [s.kind for s in plan_steps(goal)] for name, goal in GOALS.items()}
    assert kinds == {
        "soup_and_sauce_in_basket": ["place", "place"],
        "stove_and_moka": ["turn", "place"],
        "bowl_in_drawer_and_close": ["place", "close"],
        "two_moka_pots": ["turn", "place", "place"],
        "mug_in_microwave": ["place", "close"],
    }
    steps = plan_steps(GOALS["two_moka_pots"])
    assert steps[1] == Step("place", ("moka_pot_1", "flat_stove_1_cook_region", "on"))
    assert steps[2].names[0] == "moka_pot_2"


def test_a_closed_drawer_is_pulled_open_before_placing_into_it():
    goal = [["in", "akita_black_bowl_1", "cabinet_1_top_region"], ["in", "bowl_2", "cabinet_1_top_region"]]
    steps = plan_steps(goal, drawer_closed=lambda region: region == "cabinet_1_top_region")
    assert [s.kind for s in steps] == ["pull", "place", "place"]  # one pull for both
    assert [s.kind for s in plan_steps(goal, drawer_closed=lambda region: False)] == ["place", "place"]
    assert [s.kind for s in plan_steps(goal, drawer_closed=lambda region: None)] == ["place", "place"]


def test_a_predicate_without_a_step_is_one_clear_line():
    with pytest.raises(ValueError, match="no step for the goal predicate") as err:
        plan_steps([["open", "microwave_1"], ["turnoff", "flat_stove_1"]])
    assert "\n" not in str(err.value)


def test_objects_sharing_a_target_are_spread_along_it():
    steps = plan_steps(GOALS["two_moka_pots"])
    assert spread_offsets(steps, 0.08) == pytest.approx([0.0, -0.04, 0.04])
    steps = plan_steps(GOALS["stove_and_moka"])
    assert spread_offsets(steps, 0.08) == [0.0, 0.0]


def _ring(centre, radius, n, top=0.1) -> list[tuple[np.ndarray, np.ndarray]]:
    out = []
    for k in range(n):
        a = 2 * np.pi * k / n
        out.append(
            (np.array([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a), top / 2]), None)
        )
    return out


def test_a_mugs_cup_and_handle_from_its_boxes():
    """Wall boxes on a circle of radius 0.04 about (0.01, -0.01) from the origin, a handle sticking out along +y:
    the cup's centre and radius, and the handle's boxes (an obstacle for the fingers)."""
    origin = np.array([0.3, 0.2, 0.9])
    centre = origin[:2] + np.array([0.01, -0.01])
    walls = [c for c, _ in _ring(centre, 0.04, 12)]
    handle = [np.array([centre[0], centre[1] + y, 0.05]) for y in (0.055, 0.065)]
    bottom = [np.array([*centre, 0.005])]
    pts = np.array(walls + handle + bottom)
    n = len(pts)
    boxes = Boxes(pts, np.repeat(np.eye(3)[None], n, axis=0), np.full((n, 3), 0.004))
    off, radius, h = cup_geometry(boxes, origin, handle_out=0.012)
    np.testing.assert_allclose(off, [0.01, -0.01], atol=2e-3)
    assert radius == pytest.approx(0.04, abs=2e-3)
    assert len(h) == 2 and np.all(h.centre[:, 1] > centre[1] + 0.05)


# ----- in the simulator (the LIBERO venv) -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def env():
    from gazereg.envs.libero.env import LiberoEnv

    e = LiberoEnv("libero_10", cameras=(), max_steps=520)  # seed s: task s % 10, initial state s // 10
    yield e
    e.close()


def _roll(env, seed: int) -> tuple[LongExpert, dict]:
    env.reset(seed=seed)
    ex = LongExpert(noise=0.0)
    ex.reset(env, noise_seed=[seed, 0])
    info: dict = {}
    for _ in range(520):
        _, _, terminated, _, info = env.step(ex(env))
        if terminated:
            break
    return ex, info


@pytest.mark.slow
@pytest.mark.libero
def test_every_task_has_a_plan(env):
    """Each of the ten goals composes a plan on its initial state 0, with every step kind but pull (no LIBERO-10
    drawer starts closed) and the gaze parts of every step from the first frame on."""
    kinds = {}
    for seed in range(10):
        env.reset(seed=seed)
        ex = LongExpert()
        ex.reset(env, noise_seed=[seed, 0])
        a = ex(env)
        assert a.shape == (7,) and a.dtype == np.float32 and np.all(np.abs(a) <= 1)
        parts = ex.gaze_points(env)
        assert set(ex.gaze_targets) - {"obj", "goal"} == set(parts), (ex.gaze_targets, list(parts))
        kinds[env.task_names[env.task_index]] = ex.kind
    assert {k for kind in kinds.values() for k in kind.split("+")} == {"turn", "place", "close"}
    assert kinds["KITCHEN_SCENE8_put_both_moka_pots_on_the_stove"] == "turn+place+place"
    assert kinds["KITCHEN_SCENE4_put_the_black_bowl_in_the_bottom_drawer_of_the_cabinet_and_close_it"] == (
        "place+close"
    )


@pytest.mark.slow
@pytest.mark.libero
def test_the_expert_turns_the_stove_on_and_puts_the_moka_pot_on_it(env):
    """Task 2 (about 210 steps): a knob, then a placement."""
    ex, info = _roll(env, 2)
    assert env.task_names[env.task_index] == "KITCHEN_SCENE3_turn_on_the_stove_and_put_the_moka_pot_on_it"
    assert info["success"], (ex.kind, ex.phase, info["steps"])


@pytest.mark.slow
@pytest.mark.libero
def test_a_collected_two_mug_episode_succeeds_and_names_both_mugs_for_the_gaze():
    """Task 4 (two mugs onto two plates, about 230 steps) collected: success, the second mug and its plate are
    gaze targets with positions, image points and contact for every frame, the hand touching the mug only
    after a while."""
    from gazereg.envs.libero.collector import rollout_libero_expert
    from gazereg.envs.libero.env import LiberoEnv

    e = LiberoEnv("libero_10/4", cameras=("agentview",), image_size=64, max_steps=520)
    try:
        ep, summary = rollout_libero_expert(e, seed=0)
    finally:
        e.close()
    assert summary["success"], summary
    assert ep.meta["gaze_targets"] == ["obj", "goal", "obj2", "goal2"]
    T = ep.length
    for key in ("obj2_pos", "obj2_uv.agentview", "contact.obj2", "goal2_pos", "contact.goal2"):
        assert ep.extras[key].shape[0] == T, key
    touched = ep.extras["contact.obj2"]
    assert touched.any() and not touched[0]
    assert ep.extras["contact.goal2"][-1] and not ep.extras["contact.goal2"][0]
