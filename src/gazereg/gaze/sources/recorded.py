"""Recorded gaze (`recorded`): per-frame gaze points stored with the episode, e.g. from an eye tracker.

The episode carries `extra.gaze_uv.<camera>` (T, 2) normalised (u right, v down) in the stored frame, NaN where
the tracker lost the eye, and optionally `extra.gaze_valid.<camera>` (T,) bool. Points become Gaussian maps.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from gazereg.data.store import Episode
from gazereg.gaze.sources import register_gaze_source
from gazereg.gaze.sources.params import GazeSourceParams
from gazereg.heatmaps import heatmaps_from_points
from gazereg.runtime.errors import UsageError


@dataclass(frozen=True)
class RecordedParams(GazeSourceParams):
    """`sigma`: Gaussian standard deviation as a fraction of the map width (0.05 of 64 cells = 3.2);
    `key`: the extras' name before `.<camera>`."""

    name: ClassVar[str] = "recorded"
    sigma: float = 0.05
    key: str = "gaze_uv"

    def __post_init__(self) -> None:
        if self.sigma <= 0:
            raise UsageError(f"sigma must be > 0, got {self.sigma}")


@register_gaze_source(RecordedParams)
class RecordedGaze:
    name = "recorded"

    def __init__(self, params: RecordedParams = RecordedParams()):
        self.params = params
        self.sigma, self.key = params.sigma, params.key

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "sigma": self.sigma, "key": self.key}

    def __call__(self, episode: Episode, camera: str, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        key = f"{self.key}.{camera}"
        if key not in episode.extras:
            have = sorted(k for k in episode.extras if k.startswith(self.key))
            raise UsageError(
                f"episode {episode.index} has no recorded gaze {key!r} (it has {have or 'none'}): the recorded "
                "source reads eye tracking stored with the episodes (e.g. imported with a gaze column)"
            )
        valid = episode.extras.get(f"gaze_valid.{camera}")
        maps, ok = heatmaps_from_points(
            np.asarray(episode.extras[key]),
            size,
            self.sigma * size[1],
            valid=None if valid is None else np.asarray(valid),
        )
        return maps.numpy(), ok.numpy()
