"""gazereg's copy of Meta-World's difficulty groups is LeRobot's (`lerobot-eval --env.task=easy` etc.)."""

from __future__ import annotations

import json
from importlib import resources

from gazereg.envs.metaworld.difficulty import DIFFICULTY


def test_the_difficulty_groups_are_lerobots():
    config = json.loads(resources.files("lerobot.envs").joinpath("metaworld_config.json").read_text())
    theirs = config["DIFFICULTY_TO_TASKS"]
    assert {g: tuple(t) for g, t in theirs.items()} == DIFFICULTY
