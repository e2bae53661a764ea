"""The pick-and-place expert's re-grasp (pure numpy; no LIBERO): an object found `slip` lower in the hand than
when grasped sends the expert back to `above`, at most `retries` times, and `regrasps` counts them."""

from __future__ import annotations

import numpy as np

from gazereg.envs.libero.expert import PHASES, SpatialExpert

HAND_OVER_OBJECT = {"hand": np.array([0.0, 0.0, 0.30]), "obj": np.array([0.0, 0.0, 0.0])}


def carrying(ex: SpatialExpert) -> None:
    ex.phase, ex._hold, ex._offset_z = "carry", np.zeros(3), 0.10


def test_a_dropped_object_starts_the_grasp_over_until_the_retries_are_spent():
    ex = SpatialExpert()
    assert ex.regrasps == 0
    for k in range(1, ex.p.retries + 1):
        carrying(ex)
        assert ex._advance(False, HAND_OVER_OBJECT)
        assert ex.phase == PHASES[0] and ex.regrasps == k
    carrying(ex)
    assert not ex._advance(False, HAND_OVER_OBJECT)  # retries spent: it carries on with nothing in hand
    assert ex.phase == "carry" and ex.regrasps == ex.p.retries


def test_an_object_held_where_it_was_grasped_is_not_a_drop():
    ex = SpatialExpert()
    carrying(ex)
    held = {"hand": np.array([0.0, 0.0, 0.10]), "obj": np.array([0.0, 0.0, 0.0])}
    ex._advance(False, held)
    assert ex.phase == "carry" and ex.regrasps == 0


def test_the_goal_expert_reports_its_placers_regrasps():
    from gazereg.envs.libero.expert_goal import GoalExpert

    ex = GoalExpert()
    assert ex.regrasps == 0  # no placement yet
    placer = SpatialExpert()
    placer._tries = 2
    ex._placer = placer
    assert ex.regrasps == 2
