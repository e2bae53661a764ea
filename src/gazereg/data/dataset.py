"""Training samples from an episode store, with gaze targets on the policy's patch grid.

One sample is one frame t of one episode:

    image.<camera>  uint8   (H, W, 3)   the stored frame (the policy resizes it)
    state           float32 (S,)        raw proprioception (the policy normalises it)
    action          float32 (K, A)      actions t .. t+K-1, the last one repeated past the episode end
    action_pad      bool    (K,)        True where t+k is past the episode end (excluded from the loss)
    text_ids        long    (L,)        the tokenized instruction; text_mask bool (L,)
    gaze            float32 (N,)        the prior mapped onto the policy's patch grid (only with a prior)
    gaze_valid      bool    ()          False where the frame has no usable gaze
    index, episode, t  long ()          bookkeeping

Gaze priors are mapped to patch distributions once, when the data set is built (`patch_distribution` with
the policy's own geometry), and cached in memory as an (n_frames, N) table; a training step only indexes it.
Frames are copied into one contiguous uint8 tensor per camera (`in_memory=True`, the default) or read from
the store's memory maps per sample. `__getitems__` builds a whole batch at once (the DataLoader uses it).
The order of samples is owned by `StepBatchSampler`: a pure function of (seed, step), so a resumed run
sees exactly the batches an uninterrupted one would.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor

from gazereg.data.store import EpisodeStore, MissingPriorError
from gazereg.patches import PatchGeometry, patch_distribution
from gazereg.runtime.errors import UsageError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class StoreInfo:
    """What a policy needs to know about its training data before it is built."""

    cameras: tuple[str, ...]
    camera_hw: tuple[tuple[int, int], ...]
    state_dim: int
    action_dim: int
    instructions: tuple[str, ...]  # sorted unique
    tasks: tuple[str, ...]  # sorted unique
    n_frames: int


def select_episodes(
    store: EpisodeStore, tasks: Sequence[str] = (), max_episodes: int | None = None
) -> list[int]:
    """Episode indices of the store, optionally only some tasks and at most max_episodes per task; a selection
    that matches nothing is a `UsageError` that lists the store's tasks."""
    out, per_task = [], {}
    for i in store.indices():
        task = store.meta(i)["task"]
        if tasks and task not in tasks:
            continue
        if max_episodes is not None and per_task.get(task, 0) >= max_episodes:
            continue
        per_task[task] = per_task.get(task, 0) + 1
        out.append(i)
    if not out:
        have = sorted({store.meta(i)["task"] for i in store.indices()})
        if not have:
            raise UsageError(f"store {store.root} has no episodes")
        raise UsageError(
            f"no episodes selected from {store.root}: tasks {', '.join(tasks)} match none of its tasks "
            f"({', '.join(have)})"
        )
    return out


def split_episodes(
    store: EpisodeStore, episodes: Sequence[int], val_fraction: float, seed: int
) -> tuple[list[int], list[int]]:
    """The policy trainer's validation split, random and seeded, stratified by task: round(val_fraction * n)
    episodes of each task are held out (at least one overall when val_fraction > 0 and there are >= 2
    episodes; never a task's last episode). Returns (train, validation) indices. (GLC's held-out episodes
    are chosen differently, deterministically: `gazereg.gaze.glc.evaluate.holdout_split`.)"""
    if not 0 <= val_fraction < 1:
        raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
    by_task: dict[str, list[int]] = {}
    for i in episodes:
        by_task.setdefault(store.meta(i)["task"], []).append(i)
    g = torch.Generator().manual_seed(seed)
    val: list[int] = []
    for task in sorted(by_task):
        eps = by_task[task]
        perm = torch.randperm(len(eps), generator=g).tolist()
        n_val = min(len(eps) - 1, round(val_fraction * len(eps)))
        val += [eps[j] for j in perm[:n_val]]
    if val_fraction > 0 and not val and len(episodes) >= 2:
        biggest = max(sorted(by_task), key=lambda t: len(by_task[t]))
        val = [by_task[biggest][-1]] if len(by_task[biggest]) > 1 else [episodes[-1]]
    val_set = set(val)
    return [i for i in episodes if i not in val_set], sorted(val)


def describe_store(store: EpisodeStore, episodes: Sequence[int], cameras: Sequence[str] = ()) -> StoreInfo:
    """Cameras (default: all of the first episode's, sorted), frame sizes and dimensions; checks consistency
    (a camera some episode lacks is a `UsageError`)."""
    metas = [store.meta(i) for i in episodes]
    cams = tuple(cameras) if cameras else tuple(sorted(metas[0]["cameras"]))
    hw: dict[str, tuple[int, int]] = {}
    for m in metas:
        for cam in cams:
            if cam not in m["cameras"]:
                raise UsageError(
                    f"camera {cam!r}: episode {m['index']} of store {store.root} has no such camera; "
                    f"it has {', '.join(sorted(m['cameras']))}"
                )
            size = tuple(m["cameras"][cam])
            if hw.setdefault(cam, size) != size:
                raise ValueError(
                    f"camera {cam!r} frames are {hw[cam]} in some episodes and {size} in episode {m['index']}"
                )
    ep0 = store.read(episodes[0], cameras=list(cams))
    S, A = ep0.state.shape[1], ep0.action.shape[1]
    instructions, tasks = set(), set()
    n = 0
    for i, m in zip(episodes, metas):
        ep = store.read(i, cameras=[])
        if ep.state.shape[1] != S or ep.action.shape[1] != A:
            raise ValueError(
                f"episode {i} has state/action dims {ep.state.shape[1]}/{ep.action.shape[1]}, episode {episodes[0]} {S}/{A}"
            )
        instructions.add(ep.instruction)
        tasks.add(ep.task)
        n += m["length"]
    return StoreInfo(
        cams, tuple(hw[c] for c in cams), int(S), int(A), tuple(sorted(instructions)), tuple(sorted(tasks)), n
    )


class EpisodeDataset(torch.utils.data.Dataset):
    """Frames of the given episodes as training samples (see the module docstring for the fields).

    Args:
        store, episodes, cameras: what to read.
        chunk: K, actions per sample.
        tokenizer: a callable list[str] -> (ids (B, L), mask (B, L)) (the policy's tokenizer).
        gaze_prior, gaze_camera, geometry: with a prior name, its heatmaps are mapped onto `geometry`'s patch
            grid (the policy's geometry of `gaze_camera`, default: the camera recorded in prior.json).
        gaze_eps: epsilon floor of the patch distributions.
        in_memory: copy frames into RAM (fast batches) instead of reading the memory maps per sample.
    """

    def __init__(
        self,
        store: EpisodeStore,
        episodes: Sequence[int],
        cameras: Sequence[str],
        chunk: int,
        tokenizer: Any,
        gaze_prior: str | None = None,
        gaze_camera: str | None = None,
        geometry: PatchGeometry | None = None,
        gaze_eps: float = 1e-6,
        in_memory: bool = True,
    ):
        if not episodes:
            raise ValueError("an EpisodeDataset needs at least one episode")
        self.store, self.episodes, self.cameras, self.chunk = store, list(episodes), list(cameras), int(chunk)
        self.in_memory = in_memory
        self.lengths = torch.tensor([int(store.meta(i)["length"]) for i in self.episodes], dtype=torch.long)
        self.offsets = torch.cat([torch.zeros(1, dtype=torch.long), self.lengths.cumsum(0)[:-1]])
        n = int(self.lengths.sum())
        self.ep_of = torch.repeat_interleave(
            torch.arange(len(self.episodes)), self.lengths
        )  # (n,) position in self.episodes
        self.t_of = torch.arange(n) - self.offsets[self.ep_of]
        self.frames: dict[str, Tensor] | None = None
        self._mmaps: dict[str, list[np.ndarray]] | None = None
        self.state, self.action, self.instructions = self._read_episodes(n)
        self.text_ids, self.text_mask = tokenizer(self.instructions)  # (E, L)
        self.gaze: Tensor | None = None
        self.gaze_valid: Tensor | None = None
        self.gaze_camera: str | None = None
        if gaze_prior is not None:
            self._load_gaze(gaze_prior, gaze_camera, geometry, gaze_eps)

    def _read_episodes(self, n: int) -> tuple[Tensor, Tensor, list[str]]:
        """(n, S) states and (n, A) actions as float32 and each episode's instruction; frames into one (n, H, W,
        3) uint8 tensor per camera (`in_memory`) or kept as each episode's memory map. Episodes are read one
        at a time, so the open files are the kept frame maps at most (a store of thousands of episodes would
        otherwise hold every episode's arrays open at once and run out of file descriptors)."""
        states, actions, instructions = [], [], []
        frames: dict[str, np.ndarray] = {}
        mmaps: dict[str, list[np.ndarray]] = {c: [] for c in self.cameras}
        for pos, i in enumerate(self.episodes):
            e = self.store.read(i, cameras=self.cameras)
            if e.length != int(self.lengths[pos]):
                raise ValueError(
                    f"episode {i} has {e.length} frames, its meta.json says {int(self.lengths[pos])}"
                )
            states.append(np.array(e.state, dtype=np.float32))
            actions.append(np.array(e.action, dtype=np.float32))
            instructions.append(e.instruction)
            lo, hi = int(self.offsets[pos]), int(self.offsets[pos]) + e.length
            for c in self.cameras:
                if not self.in_memory:
                    mmaps[c].append(e.frames[c])
                    continue
                if c not in frames:
                    frames[c] = np.empty((n, *e.frames[c].shape[1:]), dtype=e.frames[c].dtype)
                frames[c][lo:hi] = e.frames[c]
            del e  # its memory maps close here
        if self.in_memory:
            self.frames = {c: torch.from_numpy(f) for c, f in frames.items()}
        else:
            self._mmaps = mmaps
        return (
            torch.from_numpy(np.concatenate(states)),
            torch.from_numpy(np.concatenate(actions)),
            instructions,
        )

    # ----- gaze ----------------------------------------------------------------------------------------------
    def _load_gaze(self, name: str, camera: str | None, geometry: PatchGeometry | None, eps: float) -> None:
        info = self.store.prior_info(name)
        recorded = info.get("camera")
        asked, camera = camera, camera or recorded
        if camera is None:
            raise UsageError(
                f"prior {name!r} does not record its camera (prior.json); pass the gaze camera explicitly"
            )
        if camera not in self.cameras:
            raise UsageError(
                f"prior {name!r} is for camera {camera!r}, which the policy does not see (cameras {self.cameras})"
            )
        if recorded is not None and camera != recorded:
            raise UsageError(
                f"prior {name!r} was made for camera {recorded!r}, not {asked!r}: a prior regularizes only the "
                "camera it was made for"
            )
        if geometry is None:
            raise ValueError("mapping gaze onto patches needs the policy's image geometry of the gaze camera")
        missing = [i for i in self.episodes if not self.store.has_prior(name, i)]
        if missing:
            raise MissingPriorError(
                f"{len(missing)} episode(s) have no {name!r} prior (first: {missing[:5]}); run `gazereg priors` for the store"
            )
        dists, valids = [], []
        for i, T in zip(self.episodes, self.lengths.tolist()):
            heat, valid = self.store.read_prior(name, i)  # refuses a prior made from another episode
            if heat.shape[0] != T:
                raise UsageError(f"prior {name!r} of episode {i} has {heat.shape[0]} frames, the episode {T}")
            d, ok = patch_distribution(heat, geometry, valid, eps=eps)
            dists.append(d)
            valids.append(ok)
        self.gaze, self.gaze_valid, self.gaze_camera = torch.cat(dists), torch.cat(valids), camera
        self.gaze_geometry = geometry
        frac = float(self.gaze_valid.float().mean())
        if frac < 0.5:
            log.warning("prior %r: only %.0f%% of the training frames have valid gaze", name, 100 * frac)

    # ----- samples -------------------------------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.state.shape[0])

    def _frames(self, cam: str, rows: Tensor) -> Tensor:
        if self.frames is not None:
            return torch.index_select(
                self.frames[cam], 0, rows
            )  # much faster than advanced indexing for uint8
        assert self._mmaps is not None
        e, t = self.ep_of[rows].tolist(), self.t_of[rows].tolist()
        return torch.from_numpy(np.stack([np.asarray(self._mmaps[cam][ei][ti]) for ei, ti in zip(e, t)]))

    def __getitems__(self, indices: Sequence[int]) -> dict[str, Tensor]:
        """A whole batch (B = len(indices)) as a dict of stacked tensors."""
        rows = torch.as_tensor(list(indices), dtype=torch.long)
        if rows.numel() and (rows.min() < 0 or rows.max() >= len(self)):
            raise IndexError(f"sample indices out of range for {len(self)} samples")
        ep, t = self.ep_of[rows], self.t_of[rows]
        k = torch.arange(self.chunk)
        T = self.lengths[ep]
        pad = (t[:, None] + k[None]) >= T[:, None]  # (B, K)
        chunk_rows = rows[:, None] + torch.minimum(k[None], (T - 1 - t)[:, None])  # repeat the last action
        out: dict[str, Tensor] = {f"image.{c}": self._frames(c, rows) for c in self.cameras}
        out.update(
            state=torch.index_select(self.state, 0, rows),
            action=torch.index_select(self.action, 0, chunk_rows.flatten()).view(*chunk_rows.shape, -1),
            action_pad=pad,
            text_ids=self.text_ids[ep],
            text_mask=self.text_mask[ep],
            index=rows,
            episode=torch.as_tensor(self.episodes)[ep],
            t=t,
        )
        if self.gaze is not None:
            assert self.gaze_valid is not None
            out["gaze"], out["gaze_valid"] = self.gaze[rows], self.gaze_valid[rows]
        return out

    def __getitem__(self, index: int) -> dict[str, Tensor]:
        return {k: v[0] for k, v in self.__getitems__([index]).items()}

    def stats(self) -> dict[str, np.ndarray]:
        """Mean and std (population) of state and action over every frame (float64 accumulation)."""
        s, a = self.state.double(), self.action.double()
        return {
            "state_mean": s.mean(0).float().numpy(),
            "state_std": s.std(0, unbiased=False).float().numpy(),
            "action_mean": a.mean(0).float().numpy(),
            "action_std": a.std(0, unbiased=False).float().numpy(),
        }


def collate_batch(batch: Any) -> dict[str, Tensor]:
    """DataLoader collate: `__getitems__` already returns a stacked batch; single samples are stacked."""
    if isinstance(batch, dict):
        return batch
    return {k: torch.stack([b[k] for b in batch]) for k in batch[0]}


class StepBatchSampler(torch.utils.data.Sampler[list[int]]):
    """Batches for steps start_step .. total_steps-1, a pure function of (seed, step).

    Global sample position p = step * global_batch + j walks through a fresh seeded permutation every epoch
    (epoch = p // n). Process `rank` of `world` takes positions j = rank, rank + world, ... of each global
    batch, so every process sees a disjoint share and a resumed run continues exactly."""

    def __init__(
        self,
        n: int,
        global_batch: int,
        seed: int,
        total_steps: int,
        start_step: int = 0,
        rank: int = 0,
        world: int = 1,
    ):
        if global_batch % world:
            raise ValueError(f"batch size {global_batch} is not divisible by the {world} processes")
        if n <= 0:
            raise ValueError("no training samples")
        self.n, self.batch, self.seed = n, global_batch, seed
        self.total, self.start, self.rank, self.world = total_steps, start_step, rank, world
        self._perms: dict[int, Tensor] = {}

    def _perm(self, epoch: int) -> Tensor:
        if epoch not in self._perms:
            self._perms = {e: p for e, p in self._perms.items() if e >= epoch - 1}
            self._perms[epoch] = torch.randperm(
                self.n, generator=torch.Generator().manual_seed(self.seed * 1_000_003 + epoch)
            )
        return self._perms[epoch]

    def batch_indices(self, step: int) -> list[int]:
        pos = step * self.batch + torch.arange(self.rank, self.batch, self.world)
        epochs = (pos // self.n).tolist()
        return [int(self._perm(e)[p % self.n]) for e, p in zip(epochs, pos.tolist())]

    def __iter__(self) -> Iterator[list[int]]:
        for step in range(self.start, self.total):
            yield self.batch_indices(step)

    def __len__(self) -> int:
        return max(0, self.total - self.start)

    def epoch_of(self, step: int) -> float:
        return step * self.batch / self.n


def steps_per_epoch(n: int, batch: int) -> int:
    return max(1, math.ceil(n / batch))
