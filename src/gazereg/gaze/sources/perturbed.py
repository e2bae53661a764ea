"""Perturbed gaze (`perturbed`): controls that keep a prior's statistics but break its link to the task.

Modes (all deterministic per episode and seed):
  blobs          10 random 5x5-cell squares per frame (the authors' corrupted-gaze variant, on our grid);
  shuffle        the base prior with its blocks of `block` x `block` cells spatially permuted (one
                 permutation per episode);
  other_episode  the base prior of another episode (a fixed derangement of the store's episodes, of any
                 task), resampled in time to this length;
  same_task      the same, deranged within each task's episodes: the task's region (where its objects
                 tend to be) without this episode's locations; a task with one episode is refused.
`shuffle`, `other_episode` and `same_task` read an existing prior (`base`) from the same store.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Literal, get_args

import numpy as np

from gazereg.data.store import Episode, EpisodeStore
from gazereg.gaze.sources import register_gaze_source
from gazereg.gaze.sources.params import GazeSourceParams
from gazereg.runtime.errors import UsageError

PerturbationMode = Literal["blobs", "shuffle", "other_episode", "same_task"]
PERTURBATION_MODES: tuple[str, ...] = get_args(PerturbationMode)


@dataclass(frozen=True)
class PerturbedParams(GazeSourceParams):
    """`mode`: the perturbation (module docstring); `base`: the stored prior that `shuffle` and
    `other_episode` and `same_task` perturb; `seed`; `n_blobs` squares of `blob_cells` x `blob_cells` cells per frame
    (`blobs`); `block`: side of the shuffled blocks, cells (`shuffle`)."""

    name: ClassVar[str] = "perturbed"
    mode: PerturbationMode = "shuffle"
    base: str = "visuomotor"
    seed: int = 0
    n_blobs: int = 10
    blob_cells: int = 5
    block: int = 8

    def __post_init__(self) -> None:
        if self.mode not in PERTURBATION_MODES:
            raise UsageError(
                f"unknown perturbation {self.mode!r}; use one of {', '.join(PERTURBATION_MODES)}"
            )


@register_gaze_source(PerturbedParams)
class PerturbedGaze:
    name = "perturbed"

    def __init__(self, params: PerturbedParams = PerturbedParams()):
        self.params = params
        self.mode, self.base, self.seed = params.mode, params.base, params.seed
        self.n_blobs, self.blob_cells, self.block = params.n_blobs, params.blob_cells, params.block
        self.store: EpisodeStore | None = None
        self._tasks: dict[int, str] | None = None  # episode index -> task (`same_task`), read on first use

    def bind(self, store: EpisodeStore) -> None:
        """Give the source the store it reads base priors from (the prior pipeline calls this); a base prior
        the store does not hold is refused here, before anything is made (`MissingPriorError`)."""
        if self.mode != "blobs":
            store.prior_info(self.base)
        self.store, self._tasks = store, None

    def describe(self) -> dict[str, Any]:
        d = {"name": self.name, "mode": self.mode, "seed": self.seed}
        if self.mode == "blobs":
            d.update(n_blobs=self.n_blobs, blob_cells=self.blob_cells)
        else:
            d.update(base=self.base, block=self.block)
        return d

    def _base(self, index: int, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        if self.store is None:
            raise RuntimeError("perturbed gaze needs a store: call bind(store) before use")
        heat, valid = self.store.read_prior(self.base, index)
        if heat.shape[1:] != tuple(size):
            raise UsageError(
                f"base prior {self.base!r} is {heat.shape[1:]}, requested {size}: use the same size"
            )
        return heat, valid

    def __call__(self, episode: Episode, camera: str, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng([self.seed, episode.index])
        T = episode.length
        if self.mode == "blobs":
            maps = np.zeros((T, *size), np.float32)
            b = min(self.blob_cells, *size)
            for t in range(T):
                for _ in range(self.n_blobs):
                    i, j = rng.integers(0, size[0] - b + 1), rng.integers(0, size[1] - b + 1)
                    maps[t, i : i + b, j : j + b] = 1.0
            return maps / maps.sum((1, 2), keepdims=True), np.ones(T, bool)
        if self.mode == "shuffle":
            heat, valid = self._base(episode.index, size)
            k = self.block
            if size[0] % k or size[1] % k:
                raise UsageError(f"map size {size} is not divisible into {k}x{k} blocks")
            gh, gw = size[0] // k, size[1] // k
            blocks = heat.reshape(T, gh, k, gw, k).transpose(0, 1, 3, 2, 4).reshape(T, gh * gw, k, k)
            blocks = blocks[:, rng.permutation(gh * gw)]
            return blocks.reshape(T, gh, gw, k, k).transpose(0, 1, 3, 2, 4).reshape(T, *size), valid
        heat, valid = self._base(self._other(episode.index), size)
        src = np.clip(np.round(np.linspace(0, heat.shape[0] - 1, T)).astype(int), 0, heat.shape[0] - 1)
        return heat[src], valid[src]

    def _other(self, index: int) -> int:
        """The episode whose base prior episode `index` gets: a derangement, fixed by the seed, of the store's
        episodes (`other_episode`) or of each task's (`same_task`)."""
        if self.store is None:
            raise RuntimeError("perturbed gaze needs a store: call bind(store) before use")
        pool = self.store.indices()
        if self.mode == "same_task":
            if self._tasks is None:
                self._tasks = {i: self.store.meta(i)["task"] for i in pool}
            task = self._tasks[index]
            pool = [i for i in pool if self._tasks[i] == task]
            if len(pool) < 2:
                raise UsageError(f"same_task needs at least two episodes of task {task!r} in the store")
        elif len(pool) < 2:
            raise UsageError("other_episode needs at least two episodes in the store")
        perm = np.random.default_rng(self.seed).permutation(len(pool))
        pos = pool.index(index)
        other = pool[perm[pos]]
        return other if other != index else pool[perm[(pos + 1) % len(pool)]]
