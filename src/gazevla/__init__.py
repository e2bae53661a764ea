"""gazevla: gaze-regularized Vision-Language-Action policies.

The core library (no simulator, no model zoo) is importable from here; names load on first use so that
`import gazevla` stays cheap:

>>> from gazevla import heatmaps_from_points, aggregate, PatchGeometry, patch_distribution, gaze_loss, AttentionProbe
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_EXPORTS = {
    "heatmaps_from_points": "gazevla.gaze.heatmaps",
    "AggregationConfig": "gazevla.gaze.aggregation",
    "aggregate": "gazevla.gaze.aggregation",
    "PatchGeometry": "gazevla.patches",
    "patch_distribution": "gazevla.patches",
    "GazeLossConfig": "gazevla.losses",
    "WeightSchedule": "gazevla.losses",
    "gaze_kl": "gazevla.losses",
    "gaze_loss": "gazevla.losses",
    "AttentionProbe": "gazevla.attention.probe",
    "ProbeSpec": "gazevla.attention.probe",
}

__all__ = [*_EXPORTS, "__version__"]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'gazevla' has no attribute {name!r}")
