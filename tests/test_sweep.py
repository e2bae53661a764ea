"""The task sweep (issue #21, item 4): its tasks come from LeRobot's Meta-World difficulty groups by a draw fixed
in code, not by how gaze does on them; its GLC folds keep every task's prior off the GLC that saw its gaze."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from gazereg.envs.metaworld.difficulty import DIFFICULTY, difficulty_of, draw_tasks
from gazereg.envs.metaworld.instructions import INSTRUCTIONS
from gazereg.experiment.arms import fold_tasks
from gazereg.experiment.config import SWEEP_DRAW, paper, quick, sweep
from gazereg.experiment.demos import demo_collections


def test_the_groups_are_disjoint_and_hold_the_50_v3_tasks():
    tasks = [t for group in DIFFICULTY.values() for t in group]
    assert len(tasks) == len(set(tasks)) == 50
    assert {g: len(t) for g, t in DIFFICULTY.items()} == {"easy": 28, "medium": 11, "hard": 6, "very_hard": 5}
    assert set(tasks) <= set(INSTRUCTIONS)  # every one a task the environment names


def test_the_sweep_is_the_stated_draw_of_new_tasks():
    cfg = sweep()
    assert cfg.tasks == draw_tasks(SWEEP_DRAW, exclude=quick().tasks, seed=0)
    assert cfg.tasks == (
        "faucet-open-v3",
        "window-close-v3",
        "handle-press-side-v3",
        "button-press-v3",
        "coffee-push-v3",
        "soccer-v3",
        "pick-place-v3",
        "push-v3",
    )  # the docstring names them: a change to the groups or the draw must change it too
    groups = [difficulty_of(t) for t in cfg.tasks]
    assert groups == ["easy"] * 4 + ["medium"] * 2 + ["hard"] * 2
    assert not set(cfg.tasks) & set(quick().tasks)


def test_the_sweep_trains_with_the_paper_recipe_and_crossfits_glc(tmp_path):
    cfg = replace(sweep(), out=tmp_path)
    assert cfg.train == paper().train
    assert cfg.arms == ("baseline", "gaze", "glc", "location")
    assert sorted(t for fold in cfg.glc_folds for t in fold) == sorted(cfg.tasks)
    for i, fold in enumerate(cfg.glc_folds):
        trains_on, predicts = fold_tasks(cfg, i)
        assert set(predicts) == set(fold) and not set(predicts) & set(trains_on)
        assert sorted(difficulty_of(t) for t in fold) == ["easy", "easy", "hard", "medium"]
    assert "glc" not in demo_collections(cfg, Path("x"))  # cross-fitted: no GLC demonstrations of its own


def test_a_draw_depends_only_on_its_arguments():
    a = draw_tasks({"medium": 3, "hard": 1}, seed=5)
    assert a == draw_tasks({"medium": 3, "hard": 1}, seed=5)
    assert a != draw_tasks({"medium": 3, "hard": 1}, seed=6)
    assert set(draw_tasks({"hard": 6})) == set(DIFFICULTY["hard"])
    assert "push-v3" not in draw_tasks({"hard": 5}, exclude=["push-v3"])


@pytest.mark.parametrize(
    ("counts", "exclude", "message"),
    [
        ({"tricky": 1}, (), "unknown difficulty group 'tricky'"),
        ({"hard": 7}, (), "cannot draw 7 of the 6 hard tasks"),
        ({"hard": 6}, ("push-v3",), "cannot draw 6 of the 5 hard tasks"),
        ({"easy": -1}, (), "cannot draw -1"),
    ],
)
def test_impossible_draws_are_refused_naming_the_group(counts, exclude, message):
    with pytest.raises((KeyError, ValueError), match=message):
        draw_tasks(counts, exclude=exclude)


def test_a_task_outside_the_groups_is_named():
    with pytest.raises(KeyError, match="'nosuch-v3' is in no Meta-World difficulty group"):
        difficulty_of("nosuch-v3")
