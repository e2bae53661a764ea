"""Evaluation episodes stepped in lockstep: grouped by checkpoint, task and condition, at most `batch` each
(filmed ones alone); a finished episode is never stepped again while the others go on; a resumed evaluation
reruns a batch with any missing rollout whole, so each rollout always runs in the same batch."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import gazereg.evaluation.rollout as ev
from gazereg.evaluation.config import EvalConfig


class CountdownEnv:
    """Ends `seed % 4 + 2` steps after a reset (success when the last action's first entry is positive)."""

    def __init__(self):
        self.steps_taken = 0

    def reset(self, seed, options=None):
        self.left, self.seed = seed % 4 + 2, seed
        return self.obs(), {"obj_to_target": float(seed)}

    def obs(self):
        return {"state": np.full(2, self.seed, np.float32), "images": {"cam": np.zeros((4, 4, 3), np.uint8)},
                "instruction": "go"}  # fmt: skip

    def step(self, action):
        self.steps_taken += 1
        self.left -= 1
        info = {"success": bool(action[0] > 0), "obj_to_target": float(self.left)}
        if self.seed == 1003:  # a staged reward (Gym-Aloha's): up to 2, then back to 1 by the end
            info["reward"] = float(min(self.steps_taken, 2) if self.left else 1)
        return self.obs(), 0.0, self.left == 0, False, info

    def close(self):
        pass


class SignPolicy:
    """Action (sign of seed parity, 0): one call per step for the whole batch, counted."""

    config = SimpleNamespace(cameras=["cam"], camera_hw=None, image_hw=(4, 4))

    def __init__(self):
        self.calls: list[int] = []

    def reset(self):
        pass

    def select_action(self, obs, instruction):
        state = np.asarray(obs["state"])
        self.calls.append(len(state))
        return np.stack([np.where(state[:, 0] % 2 == 0, 1.0, -1.0), np.zeros(len(state))], 1)


def make_worker(batch):
    w = ev.RolloutWorker(max_steps=10, gl_backend=None, batch=batch)
    w._make_env = lambda key: CountdownEnv()
    w.envs.make = w._make_env
    w.policy_ = SignPolicy()
    w.policy = lambda checkpoint: w.policy_
    return w


def test_a_finished_episode_waits_while_the_others_go_on():
    w = make_worker(3)
    jobs = [ev.Job("a", "c", "t", "clean", seed, None) for seed in (1000, 1001, 1003)]  # 2, 3, 5 steps
    records = w.run(jobs)
    assert [r["length"] for r in records] == [2, 3, 5]
    assert [r["success"] for r in records] == [True, False, False]
    assert [r["final_distance"] for r in records] == [0.0, 0.0, 0.0]
    assert [r["min_distance"] for r in records] == [0.0, 0.0, 0.0]
    assert [r.get("max_reward") for r in records] == [None, None, 2.0]  # the highest, not the last
    assert w.policy_.calls == [3] * 5  # one call per step for the batch, until the longest episode ends
    assert [w.envs.get(("t", ("cam",), (4, 4), k)).steps_taken for k in range(3)] == [2, 3, 5]
    alone = make_worker(1)
    assert [alone.run([j])[0] for j in jobs] == records


def _jobs(videos=()):
    jobs = []
    for arm in ("a", "b"):
        for seed in range(5):
            jobs.append(
                ev.Job(arm, arm, "t", "clean", seed, f"{arm}{seed}.gif" if (arm, seed) in videos else None)
            )
    jobs.append(ev.Job("b", "b", "t", "dim:0.7", 0, None))
    return jobs


def test_jobs_are_grouped_by_checkpoint_task_and_condition_and_filmed_ones_run_alone():
    assert ev.group_jobs(_jobs(), 2) == [(0, 1), (2, 3), (4,), (5, 6), (7, 8), (9,), (10,)]
    assert ev.group_jobs(_jobs({("a", 0)}), 8) == [(0,), (1, 2, 3, 4), (5, 6, 7, 8, 9), (10,)]
    assert ev.group_jobs(_jobs(), 1) == [(i,) for i in range(11)]
    with pytest.raises(ValueError, match="filmed episode is rolled out alone"):
        make_worker(2).run([_jobs({("a", 0)})[0], _jobs()[1]])


class LoggingWorker:
    def __init__(self, calls):
        self.calls = calls

    def run(self, jobs):
        self.calls.append(tuple(j.seed for j in jobs))
        return [{"arm": j.arm, "task": j.task, "condition": j.condition, "seed": j.seed, "success": True,
                 "length": 1} for j in jobs]  # fmt: skip

    def close(self):
        pass


def test_a_resumed_evaluation_reruns_a_batch_with_a_missing_rollout_whole(tmp_path):
    ckpt = tmp_path / "ckpt"
    ckpt.mkdir()
    (ckpt / "model.safetensors").write_bytes(b"w")
    jobs = [ev.Job("a", str(ckpt), "t", "clean", s, None) for s in range(5)]
    cfg = EvalConfig(workers=1, batch=2, max_steps=3)
    log_path = tmp_path / "episodes.jsonl"
    calls: list[tuple[int, ...]] = []
    ev.run_jobs(jobs, cfg, False, log_path, lambda: LoggingWorker(calls))
    assert calls == [(0, 1), (2, 3), (4,)]
    lines = log_path.read_text().splitlines()
    log_path.write_text("\n".join(lines[:3]) + "\n")  # killed after rollout 2 was logged, 3 was not
    calls.clear()
    records = ev.run_jobs(jobs, cfg, False, log_path, lambda: LoggingWorker(calls))
    assert calls == [(2, 3), (4,)]  # rollout 2 runs again, in its own batch
    assert [r["seed"] for r in records] == [0, 1, 2, 3, 4]


def test_the_batch_defaults_to_the_simulators_lockstep():
    assert EvalConfig().lockstep() == 8  # Meta-World: small environments
    assert EvalConfig(env="libero").lockstep() == 1  # ~1.2 GB each
    assert EvalConfig(env="libero", batch=3).lockstep() == 3
