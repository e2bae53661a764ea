"""Gaze sources: where a person would look in every frame of an episode.

A source turns one episode (one camera) into per-frame heatmaps on an (h, w) grid in the image as the policy
sees it, plus a validity mask. Each source has a frozen parameters dataclass (`GazeSourceParams`, see
`gazereg.gaze.sources.params`); both register under the source's name, and one factory builds a source from
its parameters (or from its name and parameter values):

    source = make_gaze_source(VisuomotorParams(lead_time_s=0.4))     # or make_gaze_source("visuomotor", lead_time_s=0.4)
    heatmaps, valid = source(episode, camera="corner2", size=(64, 64))   # (T, h, w) float32, (T,) bool
    params = parse_source_params("glc", ["checkpoint=runs/glc/final", "stride=1"])   # command-line text

Built in: `uniform`, `saliency` (`simple`), `perturbed`, `visuomotor` (simulation), `recorded` (eye tracking
stored with the episode), `glc` (the video gaze estimator), `glc_folds` (cross-fitted GLC: each task's maps from
a GLC not trained on it). Another source comes in one of two ways:

- as a plugin (the way to ship one): an installed package declares it in the entry-point group
  `gazereg.gaze_sources` (`mygaze = "my_package.gaze:MyGazeParams"`, see `gazereg.runtime.plugins`); a name
  nobody registered is looked up there and its module imported (which registers the source), in whichever
  process asks, so `gazereg priors --source mygaze` and an experiment's workers know it;
- registered in code (`register_gaze_source`), in the process that then makes the priors.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from typing import Any, Protocol, TypeVar

import numpy as np

from gazereg.data.store import Episode
from gazereg.gaze.sources.params import GazeSourceParams, params_from_strings
from gazereg.runtime import plugins
from gazereg.runtime.errors import UsageError


class GazeSource(Protocol):
    """Callable: (episode, camera, size=(h, w)) -> (heatmaps float32 (T, h, w), valid bool (T,))."""

    name: str

    def __call__(
        self, episode: Episode, camera: str, size: tuple[int, int]
    ) -> tuple[np.ndarray, np.ndarray]: ...

    def describe(self) -> dict[str, Any]:
        """JSON-able record of the source and its parameters (stored with the priors)."""
        ...


P = TypeVar("P", bound=GazeSourceParams)
Factory = Callable[[Any], GazeSource]

_REGISTRY: dict[str, tuple[type[GazeSourceParams], Factory]] = {}
"""source name -> (its parameters dataclass, the factory that builds it from them)"""
# Sources that live in modules with heavier imports register when their module is imported.
_LAZY = {
    "uniform": "gazereg.gaze.sources.simple",
    "saliency": "gazereg.gaze.sources.simple",
    "perturbed": "gazereg.gaze.sources.perturbed",
    "recorded": "gazereg.gaze.sources.recorded",
    "visuomotor": "gazereg.gaze.sources.visuomotor",
    "glc": "gazereg.gaze.sources.glc",
    "glc_folds": "gazereg.gaze.sources.glc_folds",
}


def register_gaze_source(params: type[P]) -> Callable[[Callable[[P], GazeSource]], Callable[[P], GazeSource]]:
    """Decorator: register a factory (usually the source class, called with its parameters) under the name
    `params.name`."""
    name = params.name
    if not name:
        raise ValueError(f"{params.__name__} names no source: give it a class attribute `name`")

    def deco(factory: Callable[[P], GazeSource]) -> Callable[[P], GazeSource]:
        if name in _REGISTRY and _REGISTRY[name][1] is not factory:
            raise ValueError(f"gaze source {name!r} is already registered by {_REGISTRY[name][1]}")
        _REGISTRY[name] = (params, factory)
        return factory

    return deco


def unregister_gaze_source(name: str) -> None:
    """Forget source `name` (a built-in registers again when next asked for)."""
    _REGISTRY.pop(name, None)


def available_gaze_sources() -> list[str]:
    """The registered sources, the built-ins and those installed plugins provide, sorted."""
    return sorted(set(_REGISTRY) | set(_LAZY) | set(plugins.plugin_names(plugins.GAZE_SOURCES)))


def _entry(name: str) -> tuple[type[GazeSourceParams], Factory]:
    if name not in _REGISTRY and name in _LAZY:
        importlib.import_module(_LAZY[name])
    if name not in _REGISTRY:
        _load_plugin(name)
    if name not in _REGISTRY:
        raise UsageError(f"unknown gaze source {name!r}; available: {', '.join(available_gaze_sources())}")
    return _REGISTRY[name]


def _load_plugin(name: str) -> None:
    """Import the installed plugin that provides source `name` (its module registers it); TypeError when it
    does not register `name` after all. Nothing when no plugin provides `name`."""
    found = plugins.load_plugin(plugins.GAZE_SOURCES, name, "gaze source")
    if found is None or name in _REGISTRY:
        return
    value = plugins.plugin_value(plugins.GAZE_SOURCES, name)
    raise TypeError(
        f"{plugins.where(plugins.GAZE_SOURCES, name, value, 'gaze source')} was imported but registered no "
        f"gaze source {name!r}: its module must call register_gaze_source for a parameters class named {name!r}"
    )


def params_type(name: str) -> type[GazeSourceParams]:
    """The parameters dataclass of the registered source `name`."""
    return _entry(name)[0]


def gaze_source_params(name: str, **values: Any) -> GazeSourceParams:
    """The parameters of source `name` with `values` (the rest at their defaults); an unknown name or
    parameter is a `UsageError` that lists what exists."""
    cls = params_type(name)
    try:
        return cls(**values)
    except TypeError as e:
        raise UsageError(f"bad parameters for gaze source {name!r}: {e}") from e


def parse_source_params(name: str, items: Sequence[str]) -> GazeSourceParams:
    """The parameters of source `name` from command-line `key=value` items (`params_from_strings`)."""
    return params_from_strings(params_type(name), items)


def make_gaze_source(source: str | GazeSourceParams, **values: Any) -> GazeSource:
    """Build a gaze source from its parameters, or from its name and parameter values; unknown names and
    parameters are `UsageError`s that list what exists."""
    if isinstance(source, GazeSourceParams):
        if values:
            raise TypeError(f"pass the parameters of gaze source {source.name!r} once, not also {values}")
        params = source
    else:
        params = gaze_source_params(source, **values)
    return _entry(params.name)[1](params)
