"""A tiny synthetic episode store (no simulator): a bright square moves across a dark frame, the state
holds its position, the actions point at it, and a 'square' gaze prior is a Gaussian on it."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
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


ROOT = Path(__file__).resolve().parents[2]
TEARDOWN_ABORT = "terminate called without an active exception"


@pytest.fixture
def launch_two(tmp_path):
    """launch_two(argv_for, done) -> (CompletedProcess, folder): `accelerate launch` of argv_for(folder) with
    two CPU processes (Gloo) in a fresh folder under tmp_path.

    Launched once more, in a new folder, only when a process aborted in teardown (std::terminate with no
    exception, seen once in CI with torch 2.13) after done(folder) says the work was finished; any other
    failure, or a second abort, is returned as it is."""
    accelerate = Path(sys.executable).parent / "accelerate"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}

    def launch(argv_for, done):
        for attempt in range(2):
            folder = tmp_path / f"launch{attempt}"
            folder.mkdir()
            with socket.socket() as s:
                s.bind(("127.0.0.1", 0))
                port = s.getsockname()[1]
            cmd = [str(accelerate), "launch", "--multi_gpu", "--num_processes", "2", "--num_machines", "1"]
            cmd += ["--mixed_precision", "no", "--dynamo_backend", "no", "--main_process_port", str(port)]
            r = subprocess.run(
                cmd + argv_for(folder), capture_output=True, text=True, timeout=240, env=env, cwd=ROOT
            )
            if r.returncode == 0 or attempt or TEARDOWN_ABORT not in r.stderr or not done(folder):
                return r, folder
        raise AssertionError("unreachable")

    return launch
