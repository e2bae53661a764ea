"""scripts/lerobot_e2e_eval.py: a LeRobot checkpoint served over a pipe is rolled out by gazereg's own
evaluation (its jobs, worker and records) and reported with gazereg's success table and paired test."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from gazereg.report.ids import RunId


@pytest.fixture(scope="module")
def e2e(load_script):
    """scripts/lerobot_e2e_eval.py loaded as a module."""
    return load_script("scripts/lerobot_e2e_eval.py")


class Served:
    """A served policy as `PipePolicy` is: `reset()` and `act(images, state, task)`; records what it saw."""

    def __init__(self, action):
        self.action, self.seen, self.resets = np.asarray(action, np.float32), [], 0

    def reset(self):
        self.resets += 1

    def act(self, images, state, task):
        self.seen.append(({k: v.shape for k, v in images.items()}, np.asarray(state).shape, task))
        return self.action


def args(**changes):
    base = dict(tasks=["reach-v3"], eval_episodes=2, eval_seed=1000, eval_max_steps=6, camera="corner2",
                image_size=64, seed=1000)  # fmt: skip
    return argparse.Namespace(**{**base, **changes})


@pytest.mark.sim
def test_a_served_policy_runs_in_gazeregs_rollout_worker(e2e, tmp_path):
    a = args()
    cfg = e2e.eval_config(a, tmp_path / "eval")
    served = Served(np.full(4, 3.0))  # out of range: the adapter clips it to [-1, 1]
    policy = e2e.LanePolicy(served, a.camera, a.image_size)
    records = e2e.rollouts(policy, RunId("smolvla", a.seed), tmp_path, cfg)
    assert [(r["arm"], r["task"], r["condition"], r["seed"]) for r in records] == [
        ("smolvla@s1000", "reach-v3", "clean", 1000),
        ("smolvla@s1000", "reach-v3", "clean", 1001),
    ]
    assert all(r["length"] == 6 and r["success"] is False and "min_distance" in r for r in records)
    assert served.resets == 2 and len(served.seen) == 12
    images, state, task = served.seen[0]
    assert images == {"observation.images.corner2": (64, 64, 3)} and state == (4,)
    assert isinstance(task, str) and task
    entry = e2e.arm_results(records, "smolvla")
    assert (
        entry["success"] == [False, False] and entry["steps"] == [6, 6] and entry["task"] == ["reach-v3"] * 2
    )
    assert entry["rate"] == 0.0 and entry["wilson95"][0] == 0.0 < entry["wilson95"][1] < 1.0


def test_the_report_table_is_gazeregs_success_table(e2e):
    results = {
        "command": "python scripts/lerobot_e2e.py", "machine": "m", "wall_s": 60.0, "tasks": ["a", "b"],
        "demos": 2, "steps": 2, "gaze_source": "visuomotor", "glc": None, "setup_seeds": [1000, 1001],
        "arms": {
            "smolvla": {"success": [True, False, False, False], "task": ["a", "a", "b", "b"]},
            "smolvla_gaze": {"success": [True, True, True, False], "task": ["a", "a", "b", "b"]},
        },
        "paired": {"mcnemar": {"a_only": 0, "b_only": 2, "p_value": 0.5}},
        "attention_kl_gaze_to_attention": {"smolvla": 0.5, "smolvla_gaze": 0.25},
        "stage_seconds": {"1_collect": 60.0},
    }  # fmt: skip
    records = e2e.episode_records(results)
    assert [r["seed"] for r in records[:4]] == [1000, 1001, 1000, 1001]
    text = e2e.report_markdown(results)
    assert "| a | 1/2 [0.09, 0.91] | 2/2 [0.34, 1.00] |" in text
    assert "| pooled | 1/4 [0.05, 0.70] | 3/4 [0.30, 0.95] |" in text
    assert "exact McNemar p = 0.500" in text


def test_the_lane_policy_clips_and_batches_like_a_gazereg_policy(e2e):
    served = Served(np.array([3.0, -2.0, 0.5, 0.0]))
    policy = e2e.LanePolicy(served, "corner2", 64)
    assert policy.config.cameras == ("corner2",) and policy.config.image_hw == (64, 64)
    batch = {"state": np.zeros((2, 4), np.float32), "images": {"corner2": np.zeros((2, 64, 64, 3), np.uint8)}}
    actions = policy.select_action(batch, ["reach", "push"])
    assert actions.shape == (2, 4) and actions[0].tolist() == [1.0, -1.0, 0.5, 0.0]
    assert [task for *_, task in served.seen] == ["reach", "push"]
