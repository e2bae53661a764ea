"""A worker's environments: at most `size` open, the least recently used closed first; an evaluation worker
keeps one environment per task for every condition, each reset applying its job's perturbation, with the
same episodes as a fresh environment per condition."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from gazereg.envs.cache import EnvCache


class FakeEnv:
    def __init__(self, key, log):
        self.key, self.log = key, log
        log.append(("make", key))

    def close(self):
        self.log.append(("close", self.key))


def test_the_least_recently_used_environment_is_closed_beyond_the_limit():
    log: list[tuple[str, str]] = []
    cache = EnvCache(lambda key: FakeEnv(key, log), size=2)
    a = cache.get("a")
    assert cache.get("a") is a and log == [("make", "a")]
    cache.get("b")
    cache.get("a")  # a is now the most recent: b goes first
    cache.get("c")
    assert log[-2:] == [("close", "b"), ("make", "c")] and len(cache) == 2
    assert "a" in cache and "b" not in cache
    cache.close()
    assert sorted(log[-2:]) == [("close", "a"), ("close", "c")] and len(cache) == 0


def test_a_cache_needs_room_for_one_environment():
    with pytest.raises(ValueError, match="at least 1 environment, got size 0"):
        EnvCache(lambda key: FakeEnv(key, []), size=0)


class ImagePolicy:
    """Moves the hand by the mean brightness of its image, so that a dimmed image changes the episode."""

    config = SimpleNamespace(cameras=["corner2"], camera_hw=None, image_hw=(32, 32))

    def reset(self):
        pass

    def select_action(self, obs, instruction):
        """(n, 4) actions for a batch of n observations; (4,) for one."""
        images = np.asarray(obs["images"]["corner2"], dtype=np.float64)
        one = images.ndim == 3
        batch = images[None] if one else images
        level = batch.reshape(len(batch), -1).mean(1) / 255.0
        zeros = np.zeros_like(level)
        actions = np.stack([level - 0.3, 0.5 - level, zeros, zeros], 1).astype(np.float32)
        return actions[0] if one else actions


def test_one_environment_serves_every_condition_as_fresh_ones_would(gl_backend):
    from gazereg.evaluation.rollout import Job, RolloutWorker

    def worker():
        w = RolloutWorker(max_steps=12, gl_backend=gl_backend)
        w.policy = lambda checkpoint: ImagePolicy()
        return w

    def job(condition, seed=1000):
        return Job("a", "ckpt", "reach-v3", condition, seed, None)

    shared = worker()
    runs = [shared.run([job(c)])[0] for c in ("clean", "dim:0.7", "gaussian_noise:0.5", "clean")]
    assert len(shared.envs) == 1
    fresh = [worker().run([job(c)])[0] for c in ("clean", "dim:0.7", "gaussian_noise:0.5")]
    assert runs[:3] == fresh and runs[3] == runs[0]
    assert runs[1]["final_distance"] != runs[0]["final_distance"]  # the perturbation reached the images
    assert runs[2]["final_distance"] != runs[0]["final_distance"]
    shared.close()
    assert len(shared.envs) == 0


def test_episodes_in_lockstep_are_the_episodes_run_alone(gl_backend):
    """A batch of episodes (different setups, so they end at different steps) stepped together with one
    policy call per step gives each episode's record as a rollout of its own."""
    from gazereg.evaluation.rollout import Job, RolloutWorker

    def worker(batch):
        w = RolloutWorker(max_steps=40, gl_backend=gl_backend, batch=batch)
        w.policy = lambda checkpoint: ImagePolicy()
        return w

    jobs = [Job("a", "ckpt", "reach-v3", "dim:0.5", seed, None) for seed in (1000, 1001, 1002)]
    together = worker(3).run(jobs)
    alone = [worker(1).run([j])[0] for j in jobs]
    assert together == alone
    assert [r["seed"] for r in together] == [1000, 1001, 1002]
    assert len({r["final_distance"] for r in together}) == 3  # three different episodes
    with pytest.raises(ValueError, match="share their checkpoint, task and condition"):
        worker(2).run([jobs[0], Job("a", "ckpt", "reach-v3", "clean", 1003, None)])
