"""Simulation: Meta-World wrapper, rendering, camera geometry, perturbations, scripted experts, collection.

Names load on first use, so importing `gazevla.envs` does not import MuJoCo (the OpenGL backend is chosen
when an environment is built, see `gazevla.envs.render.select_gl_backend`).

>>> from gazevla.envs import MetaWorldEnv, make_perturbation
>>> env = MetaWorldEnv("reach-v3", cameras=("corner2",), image_size=96)   # doctest: +SKIP
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "MetaWorldEnv": "gazevla.envs.metaworld",
    "setup_of": "gazevla.envs.metaworld",
    "STATE_LAYOUT": "gazevla.envs.metaworld",
    "ACTION_LAYOUT": "gazevla.envs.metaworld",
    "CameraGeometry": "gazevla.envs.camera",
    "select_gl_backend": "gazevla.envs.render",
    "RenderBackendError": "gazevla.envs.render",
    "Lighting": "gazevla.envs.perturbations",
    "SensorNoise": "gazevla.envs.perturbations",
    "Perturbation": "gazevla.envs.perturbations",
    "make_perturbation": "gazevla.envs.perturbations",
    "parse_perturbation": "gazevla.envs.perturbations",
    "instruction_for": "gazevla.envs.instructions",
    "Expert": "gazevla.envs.experts",
    "CollectConfig": "gazevla.envs.collect",
    "collect": "gazevla.envs.collect",
    "CollectError": "gazevla.envs.collect",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'gazevla.envs' has no attribute {name!r}")
