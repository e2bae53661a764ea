"""A tiny synthetic episode store (no simulator): a bright square moves across a dark frame, the state
holds its position, the actions point at it, and a 'square' gaze prior is a Gaussian on it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gazereg.data.store import Episode, EpisodeStore

TASKS = {"reach": "reach the bright square", "press": "press the button under the square"}


def make_store(
    root: Path,
    n_episodes: int = 4,
    length: int = 12,
    size: int = 48,
    prior_size: int = 16,
    seed: int = 0,
    camera: str = "cam",
    invalid_every: int = 5,
) -> EpisodeStore:
    rng = np.random.default_rng(seed)
    store = EpisodeStore(root, create=True)
    ys, xs = np.mgrid[0:prior_size, 0:prior_size]
    for e in range(n_episodes):
        task = list(TASKS)[e % len(TASKS)]
        start, end = rng.uniform(0.15, 0.85, 2), rng.uniform(0.15, 0.85, 2)
        frac = np.linspace(0, 1, length)[:, None]
        uv = (1 - frac) * start + frac * end  # (T, 2) square centre, normalised (u right, v down)
        frames = np.full((length, size, size, 3), 20, np.uint8)
        frames += rng.integers(0, 10, frames.shape, dtype=np.uint8)
        half = max(2, size // 12)
        for t, (u, v) in enumerate(uv):
            cx, cy = int(u * size), int(v * size)
            frames[t, max(0, cy - half) : cy + half, max(0, cx - half) : cx + half] = (250, 240, 60)
        state = np.concatenate([uv, rng.normal(0, 0.1, (length, 2))], 1).astype(np.float32)
        action = np.concatenate(
            [np.gradient(uv, axis=0) * 10, np.full((length, 1), e % 2), rng.normal(0, 0.05, (length, 1))], 1
        )
        store.write(
            Episode(
                task=task,
                instruction=TASKS[task],
                frames={camera: frames},
                state=state,
                action=action.astype(np.float32),
                meta={"seed": e},
            )
        )
        heat = np.exp(
            -(
                ((xs + 0.5) / prior_size - uv[:, 0, None, None]) ** 2
                + ((ys + 0.5) / prior_size - uv[:, 1, None, None]) ** 2
            )
            / (2 * 0.06**2)
        )
        valid = np.ones(length, bool)
        if invalid_every:
            valid[::invalid_every] = False
            heat[~valid] = 0
        heat = heat / np.maximum(heat.sum((1, 2), keepdims=True), 1e-12)
        store.write_prior("square", e, heat.astype(np.float32), valid)
    store.write_prior_info(
        "square", {"camera": camera, "size": [prior_size, prior_size], "source": {"name": "synthetic"}}
    )
    return store


@pytest.fixture(scope="session")
def tiny_store(tmp_path_factory) -> EpisodeStore:
    return make_store(tmp_path_factory.mktemp("store") / "demos")
