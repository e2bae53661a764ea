"""The episode store: gazereg's on-disk format for demonstrations and the gaze priors made from them.

Layout (one folder per episode, plain `.npy` arrays so every array memory-maps with no extra dependency):

    <root>/
      store.json                      {"format": "gazereg-episodes", "version": 1}
      episodes/ep_000000/
        meta.json                     index, length, task, instruction, cameras {name: [H, W]}, fingerprint,
                                      extra meta
        frames.<camera>.npy           uint8   (T, H, W, 3)  RGB, as the policy sees it (upright)
        state.npy                     float32 (T, S)        proprioception
        action.npy                    float32 (T, A)
        extra.<name>.npy              any     (T, ...)      per-frame simulator facts (e.g. obj_uv.corner2)
      priors/<name>/
        prior.json                    the manifest: which source, checkpoint and parameters made them (written
                                      when every episode has its prior; prior.pending.json until then)
        ep_000000.npz                 heatmaps float16 (T, h, w) each summing to 1; valid bool (T,);
                                      episode: the fingerprint of the episode it was made from;
                                      settings: the settings fingerprint of the run that made it
        .writing.lock                 while a `gazereg priors` run writes (gazereg.gaze.priors)

Episodes and prior files are written to a temporary name and renamed, so a reader (or a resumed job) never
sees a half-written one: an episode folder exists completely or not at all.

Identity. An episode's `fingerprint` (16 hex digits of the SHA-256 of its arrays' names, dtypes, shapes and
bytes, its task and its instruction) is computed when it is written, and every prior file records the
fingerprint of the episode it was made from; `read_prior` refuses a prior whose episode is not the store's
(a prior copied from another store whose episode lengths happen to match, or an episode rewritten since)
with a `UsageError` naming the prior file and both fingerprints. Stores written before fingerprints keep
working: an episode without one gets it computed from its stored arrays when first needed (the same value a
new write records; it costs one read of the episode), and a prior file without one is used unchecked, with a
warning that says to recompute it.

Settings. A prior's files are one setting: prior.json (and prior.pending.json) record a `settings_fingerprint`
(gazereg.gaze.priors: 16 hex digits of the settings' SHA-256) and every prior file the fingerprint of the run
that wrote it; `read_prior` refuses a file whose fingerprint is not the manifest's (two runs with different
settings wrote into one name) with a `UsageError` naming the file. Priors made before the fingerprint are read
unchecked.

Missing episodes. An `ep_NNNNNN` folder without meta.json (a damaged copy) is not an episode, and an episode
folder deleted after a prior was made leaves that prior's file without its episode; both are left out when the
store is read, with one warning per store (the count and the first few names), not one per episode.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gazereg.data.prior_files import (  # noqa: F401 (MissingPriorError, PRIOR_MANIFEST: re-exported)
    PRIOR_MANIFEST,
    MissingPriorError,
    PriorFiles,
    first_names,
    warn_once,
)
from gazereg.runtime.io import atomic_dir, atomic_write_json

log = logging.getLogger(__name__)

FORMAT = "gazereg-episodes"
VERSION = 1
_EP_RE = re.compile(r"^ep_(\d{6})$")


def fingerprint_arrays(arrays: Mapping[str, np.ndarray], task: str, instruction: str) -> str:
    """16 hex digits of the SHA-256 of an episode's stored arrays (`{file stem: array}`: names, dtypes, shapes
    and C-order bytes, in name order), its task and its instruction: equal episodes, equal fingerprints."""
    h = hashlib.sha256(json.dumps([task, instruction]).encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"\n{name}|{a.dtype.str}|{list(a.shape)}\n".encode())
        h.update(a.reshape(-1).view(np.uint8).data)
    return h.hexdigest()[:16]


def describe_non_finite(arr: np.ndarray) -> str | None:
    """How many NaN/inf values a (T, ...) array holds and where the first is (row, then the rest of its
    index), for an error message; None when every value is finite (integer and bool arrays always are)."""
    a = np.asarray(arr)
    if a.dtype.kind not in "fc":
        return None
    bad = ~np.isfinite(a)
    if not bad.any():
        return None
    first = np.argwhere(bad)[0].tolist() if a.ndim else []
    where = f"row {first[0]}" if first else "its only value"
    if len(first) == 2:
        where += f", column {first[1]}"
    elif len(first) > 2:
        where += f", element {tuple(first[1:])}"
    return f"{int(bad.sum())} NaN/inf value(s), the first at {where} ({a[tuple(first)]})"


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
            if arr.ndim != 2:
                raise ValueError(f"{name!r} must be a finite 2-D array, got shape {arr.shape}")
            problem = describe_non_finite(arr)
            if problem is not None:
                raise ValueError(f"{name!r} must be finite but has {problem}")

    def stored_arrays(self) -> dict[str, np.ndarray]:
        """The arrays as the store saves them, by file stem (`frames.<camera>`, state, action, `extra.<name>`)."""
        arrays = {f"frames.{cam}": np.ascontiguousarray(fr) for cam, fr in self.frames.items()}
        arrays["state"] = self.state.astype(np.float32)
        arrays["action"] = self.action.astype(np.float32)
        arrays.update({f"extra.{name}": np.ascontiguousarray(arr) for name, arr in self.extras.items()})
        return arrays


class EpisodeStore(PriorFiles):
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
        self._fingerprints: dict[int, str] = {}  # episode index -> fingerprint (read or computed once)
        self._warned_unchecked: set[str] = set()  # prior names whose files carry no episode fingerprint

    # ----- episodes -----------------------------------------------------------------------------------
    def _ep_dir(self, index: int) -> Path:
        return self.root / "episodes" / f"ep_{index:06d}"

    def indices(self) -> list[int]:
        """The episodes of the store (folders ep_NNNNNN with a meta.json), sorted; folders without one are
        left out with one warning per store."""
        out, broken = [], []
        for p in (self.root / "episodes").iterdir():
            m = _EP_RE.match(p.name)
            if m and (p / "meta.json").exists():
                out.append(int(m.group(1)))
            elif m:
                broken.append(p.name)
        if broken:
            broken.sort()
            warn_once(
                ("no-meta", str(self.root.resolve()), *broken),
                "store %s: %d episode folder(s) have no meta.json and are skipped (%s): a damaged or partial "
                "copy; delete them or copy them again",
                self.root,
                len(broken),
                first_names(broken),
            )
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
        arrays = ep.stored_arrays()
        fingerprint = fingerprint_arrays(arrays, ep.task, ep.instruction)
        with atomic_dir(self._ep_dir(index)) as tmp:
            for stem, arr in arrays.items():
                np.save(tmp / f"{stem}.npy", arr)
            meta = {
                **ep.meta,
                "index": index,
                "length": ep.length,
                "task": ep.task,
                "instruction": ep.instruction,
                "cameras": {cam: list(fr.shape[1:3]) for cam, fr in ep.frames.items()},
                "fingerprint": fingerprint,
            }
            (tmp / "meta.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
        self._fingerprints[index] = fingerprint
        return index

    def meta(self, index: int) -> dict[str, Any]:
        path = self._ep_dir(index) / "meta.json"
        if not path.exists():
            raise KeyError(f"episode {index} not in store {self.root}")
        return json.loads(path.read_text())

    def episode_fingerprint(self, index: int) -> str:
        """The episode's fingerprint (module docstring): from meta.json, or computed from the stored arrays for
        an episode written before fingerprints (once per store object)."""
        if index not in self._fingerprints:
            meta = self.meta(index)
            fingerprint = meta.get("fingerprint")
            if fingerprint is None:
                arrays = {p.stem: np.load(p, mmap_mode="r") for p in self._ep_dir(index).glob("*.npy")}
                fingerprint = fingerprint_arrays(arrays, meta["task"], meta["instruction"])
            self._fingerprints[index] = str(fingerprint)
        return self._fingerprints[index]

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
