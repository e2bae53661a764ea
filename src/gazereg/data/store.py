"""The episode store: gazereg's on-disk format for demonstrations and the gaze priors made from them.

Layout (one folder per episode, plain `.npy` arrays so every array memory-maps with no extra dependency):

    <root>/
      store.json                      {"format": "gazereg-episodes", "version": 1}
      episodes/ep_000000/
        meta.json                     index, length, task, instruction, cameras {name: [H, W]}, extra meta
        frames.<camera>.npy           uint8   (T, H, W, 3)  RGB, as the policy sees it (upright)
        state.npy                     float32 (T, S)        proprioception
        action.npy                    float32 (T, A)
        extra.<name>.npy              any     (T, ...)      per-frame simulator facts (e.g. obj_uv.corner2)
      priors/<name>/
        prior.json                    which source, checkpoint and parameters made them
        ep_000000.npz                 heatmaps float16 (T, h, w) each summing to 1; valid bool (T,)

Episodes and prior files are written to a temporary name and renamed, so a reader (or a resumed job) never
sees a half-written one: an episode folder exists completely or not at all.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gazereg.runtime.io import atomic_dir, atomic_path, atomic_write_json

FORMAT = "gazereg-episodes"
VERSION = 1
_EP_RE = re.compile(r"^ep_(\d{6})$")


@dataclass
class Episode:
    """One demonstration. T frames; every per-frame array has T as its first dimension."""

    task: str
    instruction: str
    frames: dict[str, np.ndarray]  # camera -> uint8 (T, H, W, 3)
    state: np.ndarray  # float32 (T, S)
    action: np.ndarray  # float32 (T, A)
    extras: dict[str, np.ndarray] = field(default_factory=dict)  # name -> (T, ...)
    meta: dict[str, Any] = field(default_factory=dict)  # JSON-able: seed, success, fps, ...
    index: int = -1

    @property
    def length(self) -> int:
        return int(self.action.shape[0])

    def validate(self) -> None:
        """Raise ValueError naming the first inconsistency (lengths, dtypes, shapes)."""
        T = self.length
        if T == 0:
            raise ValueError(f"episode {self.index} of task {self.task!r} is empty (0 frames)")
        if not self.frames:
            raise ValueError(f"episode {self.index} has no camera frames")
        for cam, fr in self.frames.items():
            if fr.ndim != 4 or fr.shape[-1] != 3 or fr.dtype != np.uint8:
                raise ValueError(
                    f"camera {cam!r}: frames must be uint8 (T, H, W, 3), got {fr.dtype} {fr.shape}"
                )
            if fr.shape[0] != T:
                raise ValueError(f"camera {cam!r} has {fr.shape[0]} frames but the episode has {T} actions")
        for name, arr in [("state", self.state), *self.extras.items()]:
            if arr.shape[0] != T:
                raise ValueError(f"{name!r} has {arr.shape[0]} rows but the episode has {T} actions")
        for name, arr in [("state", self.state), ("action", self.action)]:
            if arr.ndim != 2 or not np.isfinite(arr).all():
                raise ValueError(f"{name!r} must be a finite 2-D array, got shape {arr.shape}")


class EpisodeStore:
    """A folder of episodes plus the gaze priors computed for them."""

    def __init__(self, root: str | Path, create: bool = False):
        self.root = Path(root)
        marker = self.root / "store.json"
        if not marker.exists():
            if not create:
                raise FileNotFoundError(
                    f"{self.root} is not an episode store (no store.json); create it first"
                )
            atomic_write_json(marker, {"format": FORMAT, "version": VERSION})
        info = json.loads(marker.read_text())
        if info.get("format") != FORMAT or info.get("version") != VERSION:
            raise ValueError(f"{marker}: unsupported store format {info}")
        (self.root / "episodes").mkdir(parents=True, exist_ok=True)

    # ----- episodes -----------------------------------------------------------------------------------
    def _ep_dir(self, index: int) -> Path:
        return self.root / "episodes" / f"ep_{index:06d}"

    def indices(self) -> list[int]:
        out = []
        for p in (self.root / "episodes").iterdir():
            m = _EP_RE.match(p.name)
            if m and (p / "meta.json").exists():
                out.append(int(m.group(1)))
        return sorted(out)

    def __len__(self) -> int:
        return len(self.indices())

    def __contains__(self, index: int) -> bool:
        return (self._ep_dir(index) / "meta.json").exists()

    def next_index(self) -> int:
        idx = self.indices()
        return idx[-1] + 1 if idx else 0

    def write(self, ep: Episode, index: int | None = None) -> int:
        """Write an episode atomically under `index` (default: the next free one); returns the index."""
        index = self.next_index() if index is None else index
        ep.index = index
        ep.validate()
        with atomic_dir(self._ep_dir(index)) as tmp:
            for cam, fr in ep.frames.items():
                np.save(tmp / f"frames.{cam}.npy", np.ascontiguousarray(fr))
            np.save(tmp / "state.npy", ep.state.astype(np.float32))
            np.save(tmp / "action.npy", ep.action.astype(np.float32))
            for name, arr in ep.extras.items():
                np.save(tmp / f"extra.{name}.npy", np.ascontiguousarray(arr))
            meta = {
                **ep.meta,
                "index": index,
                "length": ep.length,
                "task": ep.task,
                "instruction": ep.instruction,
                "cameras": {cam: list(fr.shape[1:3]) for cam, fr in ep.frames.items()},
            }
            (tmp / "meta.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
        return index

    def meta(self, index: int) -> dict[str, Any]:
        path = self._ep_dir(index) / "meta.json"
        if not path.exists():
            raise KeyError(f"episode {index} not in store {self.root}")
        return json.loads(path.read_text())

    def read(self, index: int, mmap: bool = True, cameras: list[str] | None = None) -> Episode:
        """Read an episode; arrays are memory-mapped (read-only) unless mmap=False."""
        d = self._ep_dir(index)
        meta = self.meta(index)
        mode = "r" if mmap else None
        cams = list(meta["cameras"]) if cameras is None else cameras
        missing = [c for c in cams if c not in meta["cameras"]]
        if missing:
            raise KeyError(f"episode {index} has no camera(s) {missing}; it has {list(meta['cameras'])}")
        extras = {
            p.name[len("extra.") : -len(".npy")]: np.load(p, mmap_mode=mode) for p in d.glob("extra.*.npy")
        }
        return Episode(
            task=meta["task"],
            instruction=meta["instruction"],
            frames={c: np.load(d / f"frames.{c}.npy", mmap_mode=mode) for c in cams},
            state=np.load(d / "state.npy", mmap_mode=mode),
            action=np.load(d / "action.npy", mmap_mode=mode),
            extras=extras,
            meta={k: v for k, v in meta.items() if k not in ("task", "instruction")},
            index=index,
        )

    def __iter__(self) -> Iterator[Episode]:
        for i in self.indices():
            yield self.read(i)

    # ----- priors -------------------------------------------------------------------------------------
    def prior_dir(self, name: str) -> Path:
        return self.root / "priors" / name

    def prior_names(self) -> list[str]:
        base = self.root / "priors"
        return sorted(p.name for p in base.iterdir() if (p / "prior.json").exists()) if base.exists() else []

    def write_prior_info(self, name: str, info: dict[str, Any]) -> None:
        atomic_write_json(self.prior_dir(name) / "prior.json", info)

    def prior_info(self, name: str) -> dict[str, Any]:
        path = self.prior_dir(name) / "prior.json"
        if not path.exists():
            raise FileNotFoundError(f"no priors named {name!r} in {self.root}; have {self.prior_names()}")
        return json.loads(path.read_text())

    def has_prior(self, name: str, index: int) -> bool:
        return (self.prior_dir(name) / f"ep_{index:06d}.npz").exists()

    def write_prior(self, name: str, index: int, heatmaps: np.ndarray, valid: np.ndarray) -> None:
        """Store an episode's priors: heatmaps (T, h, w) summing to 1 per valid frame, valid (T,) bool."""
        T = self.meta(index)["length"]
        if heatmaps.ndim != 3 or heatmaps.shape[0] != T or valid.shape != (T,):
            raise ValueError(
                f"priors for episode {index} must be (T={T}, h, w) + ({T},), got {heatmaps.shape}, {valid.shape}"
            )
        if not np.isfinite(heatmaps).all() or (heatmaps < 0).any():
            raise ValueError(f"priors for episode {index} contain NaN, inf or negative values")
        with atomic_path(self.prior_dir(name) / f"ep_{index:06d}.npz") as tmp, open(tmp, "wb") as f:
            np.savez(f, heatmaps=heatmaps.astype(np.float16), valid=valid.astype(bool))

    def read_prior(self, name: str, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Returns heatmaps float32 (T, h, w) and valid bool (T,)."""
        path = self.prior_dir(name) / f"ep_{index:06d}.npz"
        if not path.exists():
            raise FileNotFoundError(f"no {name!r} prior for episode {index} in {self.root}")
        with np.load(path) as z:
            heat, valid = z["heatmaps"].astype(np.float32), z["valid"].astype(bool)
        # float16 storage rounds each cell; renormalise so every valid frame sums to 1 exactly again.
        total = heat.sum(axis=(1, 2), keepdims=True)
        valid &= total[:, 0, 0] > 0
        heat = np.where(total > 0, heat / np.maximum(total, 1e-30), 0.0).astype(np.float32)
        return heat, valid
