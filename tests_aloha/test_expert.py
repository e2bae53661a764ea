"""The scripted bimanual expert solves both tasks (gym-aloha's reward 4) on setups it was not tuned on."""

from __future__ import annotations

import pytest

from gazereg.envs.aloha.collector import rollout_aloha_expert
from gazereg.envs.aloha.env import AlohaEnv


@pytest.mark.parametrize("task", ["AlohaTransferCube-v0", "AlohaInsertion-v0"])
def test_the_expert_succeeds(task):
    """Setups 100..104 (the expert was written on setups 0..19): at least 4 of 5 succeed, each before the
    episode's 400 steps; the episode records each hand's contact with its object and the gaze targets."""
    env = AlohaEnv(task, cameras=("top",), image_size=(48, 64))
    wins = 0
    for seed in range(100, 105):
        ep, summary = rollout_aloha_expert(env, seed)
        wins += summary["success"]
        assert ep.length == summary["steps"] <= 400
        assert ep.extras["contact.obj"].any() == (ep.meta["gaze_targets"][0] == "obj")
        if task == "AlohaInsertion-v0":
            assert ep.meta["gaze_targets"] == ["obj", "obj2", "goal"] and ep.extras["contact.obj2"].any()
        else:
            assert ep.meta["gaze_targets"] == ["obj", "goal"]
        assert ep.extras["obj_uv.top"].shape == (ep.length, 2)
    env.close()
    assert wins >= 4, f"{task}: {wins}/5"
