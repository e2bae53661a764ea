"""Fixtures: the test-only `toy` policy registered for a test, and a small synthetic store whose camera is a
Meta-World camera (so a policy trained on it can be rolled out in Meta-World)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from toy_policy import ToyPolicy

from gazereg.data.store import Episode, EpisodeStore
from gazereg.policies import register_policy, unregister_policy


@pytest.fixture
def toy_policy():
    """Registers ToyPolicy as policy type 'toy' for the test."""
    register_policy(ToyPolicy)
    yield ToyPolicy
    unregister_policy("toy")


def make_reach_store(
    root: Path, camera: str = "corner2", episodes: int = 4, length: int = 10, size: int = 32
):
    """A bright square drifts across a dark frame; state (4,) = its (u, v) + noise, action (4,) points along
    its motion; a 'square' gaze prior (16 x 16, a Gaussian on the square) with every 4th frame invalid."""
    rng = np.random.default_rng(0)
    store = EpisodeStore(root, create=True)
    ys, xs = (np.mgrid[0:16, 0:16] + 0.5) / 16
    for e in range(episodes):
        uv = np.linspace(rng.uniform(0.2, 0.8, 2), rng.uniform(0.2, 0.8, 2), length)  # (T, 2)
        frames = np.full((length, size, size, 3), 20, np.uint8)
        for t, (u, v) in enumerate((uv * size).astype(int)):
            frames[t, max(0, v - 3) : v + 3, max(0, u - 3) : u + 3] = (250, 240, 60)
        state = np.concatenate([uv, rng.normal(0, 0.1, (length, 2))], 1).astype(np.float32)
        action = np.concatenate([np.gradient(uv, axis=0) * 10, np.zeros((length, 2))], 1).astype(np.float32)
        store.write(Episode("reach-v3", "reach the goal", {camera: frames}, state, action, meta={"seed": e}))
        heat = np.exp(-((xs - uv[:, 0, None, None]) ** 2 + (ys - uv[:, 1, None, None]) ** 2) / 0.01)
        valid = np.arange(length) % 4 != 0
        heat[~valid] = 0
        heat /= np.maximum(heat.sum((1, 2), keepdims=True), 1e-12)
        store.write_prior("square", e, heat.astype(np.float32), valid)
    store.write_prior_info("square", {"camera": camera, "size": [16, 16], "source": {"name": "synthetic"}})
    return store


@pytest.fixture(scope="session")
def reach_store(tmp_path_factory) -> EpisodeStore:
    return make_reach_store(tmp_path_factory.mktemp("toy") / "demos")
