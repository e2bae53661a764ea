"""Gaze regularization for existing VLA frameworks, without forking them.

- `gazereg.integrations.transformers`: transformers' PI0, PaliGemma, Idefics3 / SmolVLM and Llava
  (`GazeRegularizer`, `camera_geometry`). Needs the `hf` extra (transformers >= 5).
- LeRobot: the separate `gazereg-lerobot` plugin package (lerobot_plugin/ in the repository).

Names load on first use so that importing this package does not import transformers.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "GazeRegularizer": "gazereg.integrations.transformers",
    "camera_geometry": "gazereg.integrations.transformers",
    "register_gaze_attention": "gazereg.integrations.transformers",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'gazereg.integrations' has no attribute {name!r}")
