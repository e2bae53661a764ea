"""Gaze sources: where a person would look in every frame of an episode.

A source turns one episode (one camera) into per-frame heatmaps on an (h, w) grid in the image as the policy
sees it, plus a validity mask. Sources register under a name and are built by one factory:

    source = make_gaze_source("visuomotor", lead_time_s=0.4)
    heatmaps, valid = source(episode, camera="corner2", size=(64, 64))   # (T, h, w) float32, (T,) bool

Built in: `uniform`, `saliency`, `perturbed` (here), `visuomotor` (simulation), `recorded` (eye tracking
stored with the episode), `glc` (the video gaze estimator). Third-party sources register the same way.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from gazereg.data.store import Episode


class GazeSource(Protocol):
    """Callable: (episode, camera, size=(h, w)) -> (heatmaps float32 (T, h, w), valid bool (T,))."""

    name: str

    def __call__(
        self, episode: Episode, camera: str, size: tuple[int, int]
    ) -> tuple[np.ndarray, np.ndarray]: ...

    def describe(self) -> dict[str, Any]:
        """JSON-able record of the source and its parameters (stored with the priors)."""
        ...


_REGISTRY: dict[str, Callable[..., GazeSource]] = {}
# Sources that live in modules with heavier imports register when their module is imported.
_LAZY = {
    "uniform": "gazereg.gaze.sources.simple",
    "saliency": "gazereg.gaze.sources.simple",
    "perturbed": "gazereg.gaze.sources.perturbed",
    "recorded": "gazereg.gaze.sources.recorded",
    "visuomotor": "gazereg.gaze.sources.visuomotor",
    "glc": "gazereg.gaze.sources.glc",
}


def register_gaze_source(name: str) -> Callable[[Callable[..., GazeSource]], Callable[..., GazeSource]]:
    """Decorator: register a factory (usually the source class) under `name`."""

    def deco(factory: Callable[..., GazeSource]) -> Callable[..., GazeSource]:
        if name in _REGISTRY and _REGISTRY[name] is not factory:
            raise ValueError(f"gaze source {name!r} is already registered by {_REGISTRY[name]}")
        _REGISTRY[name] = factory
        return factory

    return deco


def available_gaze_sources() -> list[str]:
    return sorted(set(_REGISTRY) | set(_LAZY))


def make_gaze_source(name: str, **params: Any) -> GazeSource:
    """Build a registered gaze source; unknown names and parameters are errors that list what exists."""
    if name not in _REGISTRY and name in _LAZY:
        importlib.import_module(_LAZY[name])
    if name not in _REGISTRY:
        raise KeyError(f"unknown gaze source {name!r}; available: {available_gaze_sources()}")
    try:
        return _REGISTRY[name](**params)
    except TypeError as e:
        raise TypeError(f"bad parameters for gaze source {name!r}: {e}") from e
