"""The gaze-prior half of the episode store: `priors/<name>/` beside `episodes/` (layout, identity and settings
checks: gazereg.data.store's module docstring). `EpisodeStore` inherits `PriorFiles`; nothing else should.

    priors/<name>/prior.json           the manifest (prior.pending.json while a `gazereg priors` run writes)
    priors/<name>/ep_NNNNNN.npz        heatmaps float16 (T, h, w), valid bool (T,), episode and settings
                                       fingerprints
"""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gazereg.runtime.errors import UsageError
from gazereg.runtime.io import atomic_path, atomic_write_json

log = logging.getLogger("gazereg.data.store")

PRIOR_MANIFEST = "prior.json"
PRIOR_PENDING = "prior.pending.json"
_PRIOR_RE = re.compile(r"^ep_(\d{6})\.npz$")
_SHOWN = 5  # names a warning lists
_warned: set[tuple[str, ...]] = set()  # what was warned about once in this process: (kind, root, ...)


def warn_once(key: tuple[str, ...], message: str, *args: Any) -> None:
    if key not in _warned:
        _warned.add(key)
        log.warning(message, *args)


def first_names(names: list[str]) -> str:
    more = f", ... ({len(names) - _SHOWN} more)" if len(names) > _SHOWN else ""
    return ", ".join(names[:_SHOWN]) + more


class MissingPriorError(UsageError, FileNotFoundError):
    """A prior name the store does not hold (or not completely): a usage mistake about a missing file."""


class PriorFiles:
    """The priors of an episode store (mixed into `EpisodeStore`, which supplies `root`, `indices`, `meta` and
    `episode_fingerprint`)."""

    root: Path
    _warned_unchecked: set[str]  # prior names whose files carry no episode fingerprint (warned once)

    if TYPE_CHECKING:  # supplied by EpisodeStore

        def indices(self) -> list[int]: ...
        def meta(self, index: int) -> dict[str, Any]: ...
        def episode_fingerprint(self, index: int) -> str: ...

    def prior_dir(self, name: str) -> Path:
        return self.root / "priors" / name

    def prior_names(self) -> list[str]:
        """The priors with a manifest (complete ones)."""
        base = self.root / "priors"
        return (
            sorted(p.name for p in base.iterdir() if (p / PRIOR_MANIFEST).exists()) if base.exists() else []
        )

    def prior_indices(self, name: str) -> list[int]:
        """The episodes that have a prior file of `name` (whether or not the prior has its manifest yet)."""
        d = self.prior_dir(name)
        found = (_PRIOR_RE.match(p.name) for p in d.iterdir()) if d.is_dir() else iter(())
        return sorted(int(m.group(1)) for m in found if m)

    def write_prior_info(self, name: str, info: dict[str, Any]) -> None:
        """Write the prior's manifest (prior.json); a pending record, if any, is removed."""
        atomic_write_json(self.prior_dir(name) / PRIOR_MANIFEST, info)
        (self.prior_dir(name) / PRIOR_PENDING).unlink(missing_ok=True)

    def write_prior_pending(self, name: str, info: dict[str, Any]) -> None:
        """Record the settings of a prior being made, until `write_prior_info` writes its manifest."""
        atomic_write_json(self.prior_dir(name) / PRIOR_PENDING, info)

    def prior_record(self, name: str) -> dict[str, Any] | None:
        """The settings a prior's files were made with: its manifest, else its pending record, else None."""
        for fname in (PRIOR_MANIFEST, PRIOR_PENDING):
            path = self.prior_dir(name) / fname
            if path.exists():
                return json.loads(path.read_text())
        return None

    def prior_info(self, name: str) -> dict[str, Any]:
        """The manifest of a complete prior; `MissingPriorError` (one line) for a name the store lacks or a
        prior whose `gazereg priors` run has not finished."""
        path = self.prior_dir(name) / PRIOR_MANIFEST
        if path.exists():
            gone = sorted(set(self.prior_indices(name)) - set(self.indices()))
            if gone:
                names = [f"ep_{i:06d}" for i in gone]
                warn_once(
                    ("gone", str(self.root.resolve()), name, *names),
                    "store %s: %d episode(s) that priors %r were made for are gone (%s); they are skipped",
                    self.root,
                    len(gone),
                    name,
                    first_names(names),
                )
            return json.loads(path.read_text())
        if (self.prior_dir(name) / PRIOR_PENDING).exists():
            done, n = len(self.prior_indices(name)), len(self.indices())
            raise MissingPriorError(
                f"priors {name!r} in {self.root} are incomplete ({done} of {n} episodes done): "
                "their `gazereg priors` run did not finish; rerun it"
            )
        raise MissingPriorError(
            f"no priors named {name!r} in {self.root}; it has {', '.join(self.prior_names()) or 'none'}"
        )

    def has_prior(self, name: str, index: int) -> bool:
        return self._prior_path(name, index).exists()

    def _prior_path(self, name: str, index: int) -> Path:
        return self.prior_dir(name) / f"ep_{index:06d}.npz"

    def write_prior(
        self, name: str, index: int, heatmaps: np.ndarray, valid: np.ndarray, settings: str | None = None
    ) -> None:
        """Store an episode's priors: heatmaps (T, h, w) summing to 1 per valid frame, valid (T,) bool; the
        file records the episode's fingerprint and `settings`, the settings fingerprint of the run making it
        (module docstring)."""
        T = self.meta(index)["length"]
        if heatmaps.ndim != 3 or heatmaps.shape[0] != T or valid.shape != (T,):
            raise ValueError(
                f"priors for episode {index} must be (T={T}, h, w) + ({T},), got {heatmaps.shape}, {valid.shape}"
            )
        if not np.isfinite(heatmaps).all() or (heatmaps < 0).any():
            raise ValueError(f"priors for episode {index} contain NaN, inf or negative values")
        arrays = {"episode": np.array(self.episode_fingerprint(index))}
        if settings is not None:
            arrays["settings"] = np.array(settings)
        with atomic_path(self._prior_path(name, index)) as tmp, open(tmp, "wb") as f:
            np.savez(f, heatmaps=heatmaps.astype(np.float16), valid=valid.astype(bool), **arrays)

    def prior_settings(self, name: str, index: int) -> str | None:
        """The settings fingerprint an episode's prior file records (None: made before it was recorded)."""
        with np.load(self._prior_path(name, index)) as z:
            return str(z["settings"]) if "settings" in z.files else None

    def check_prior(self, name: str, index: int, settings: str | None = None) -> None:
        """Refuse (`UsageError`) a prior file made from another episode than the store's episode `index`, or
        (with `settings`) by a run with other settings (a file that records none is accepted)."""
        path = self._prior_path(name, index)
        with np.load(path) as z:
            made_from = str(z["episode"]) if "episode" in z.files else None
            made_with = str(z["settings"]) if "settings" in z.files else None
        self._check_made_from(name, index, made_from)
        if settings is not None and made_with is not None and made_with != settings:
            raise UsageError(
                f"prior {path} was made with other settings (fingerprint {made_with}) than this run's "
                f"({settings}): another `gazereg priors` run wrote into {name!r}; recompute it with "
                "`gazereg priors --overwrite` or use --name to store these separately"
            )

    def _check_settings(self, name: str, path: Path, made_with: str | None) -> None:
        """Refuse a prior file whose settings fingerprint is not the one its manifest records."""
        manifest = self.prior_dir(name) / PRIOR_MANIFEST
        if not manifest.exists():
            return
        recorded = json.loads(manifest.read_text()).get("settings_fingerprint")
        if recorded is not None and made_with != recorded:
            raise UsageError(
                f"prior {path} was made with other settings (fingerprint {made_with or 'none'}) than {manifest} "
                f"records ({recorded}): two `gazereg priors` runs wrote into {name!r}; recompute it with "
                "`gazereg priors --overwrite`"
            )

    def _check_made_from(self, name: str, index: int, made_from: str | None) -> None:
        if made_from is None:
            if name not in self._warned_unchecked:
                self._warned_unchecked.add(name)
                log.warning(
                    "priors %r in %s predate episode fingerprints, so nothing checks that they were made from "
                    "this store's episodes; recompute them (gazereg priors --overwrite) to record it",
                    name,
                    self.root,
                )
            return
        have = self.episode_fingerprint(index)
        if made_from != have:
            raise UsageError(
                f"prior {self._prior_path(name, index)} was made from an episode with fingerprint {made_from}, "
                f"but episode {index} of store {self.root} has fingerprint {have}: the prior belongs to another "
                f"store (or the episode was rewritten since); recompute it with `gazereg priors --overwrite`"
            )

    def read_prior(self, name: str, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Returns heatmaps float32 (T, h, w) and valid bool (T,); a prior made from another episode than
        this store's, or with other settings than its manifest records, is refused (`UsageError`, see the
        module docstring)."""
        path = self._prior_path(name, index)
        if not path.exists():
            raise FileNotFoundError(f"no {name!r} prior for episode {index} in {self.root}")
        with np.load(path) as z:
            heat, valid = z["heatmaps"].astype(np.float32), z["valid"].astype(bool)
            made_from = str(z["episode"]) if "episode" in z.files else None
            made_with = str(z["settings"]) if "settings" in z.files else None
        self._check_made_from(name, index, made_from)
        self._check_settings(name, path, made_with)
        # float16 storage rounds each cell; renormalise so every valid frame sums to 1 exactly again.
        total = heat.sum(axis=(1, 2), keepdims=True)
        valid &= total[:, 0, 0] > 0
        heat = np.where(total > 0, heat / np.maximum(total, 1e-30), 0.0).astype(np.float32)
        return heat, valid
