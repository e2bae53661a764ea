"""Simulation: the simulator registry, Meta-World and LIBERO, rendering, camera geometry, perturbations,
scripted experts, collection.

Names load on first use, so importing `gazereg.envs` does not import MuJoCo (the OpenGL backend is chosen
when an environment is built, see `gazereg.envs.render.select_gl_backend`).

>>> from gazereg.envs import MetaWorldEnv, make_perturbation
>>> env = MetaWorldEnv("reach-v3", cameras=("corner2",), image_size=96)   # doctest: +SKIP
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "Env": "gazereg.envs.interface",
    "Simulator": "gazereg.envs.base",
    "env_class": "gazereg.envs.base",
    "make_collector": "gazereg.envs.base",
    "register_simulator": "gazereg.envs.base",
    "MetaWorldEnv": "gazereg.envs.metaworld.env",
    "setup_of": "gazereg.envs.metaworld.env",
    "STATE_LAYOUT": "gazereg.envs.metaworld.env",
    "ACTION_LAYOUT": "gazereg.envs.metaworld.env",
    "CameraGeometry": "gazereg.envs.camera",
    "select_gl_backend": "gazereg.envs.render",
    "RenderBackendError": "gazereg.envs.render",
    "Lighting": "gazereg.envs.perturbations",
    "SensorNoise": "gazereg.envs.perturbations",
    "Perturbation": "gazereg.envs.perturbations",
    "make_perturbation": "gazereg.envs.perturbations",
    "parse_perturbation": "gazereg.envs.perturbations",
    "instruction_for": "gazereg.envs.metaworld.instructions",
    "Expert": "gazereg.envs.metaworld.experts",
    "CollectConfig": "gazereg.envs.collect_config",
    "CollectError": "gazereg.envs.collect_config",
    "collect": "gazereg.envs.collect",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'gazereg.envs' has no attribute {name!r}")
