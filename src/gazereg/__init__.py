"""gazereg: gaze-regularized Vision-Language-Action policies.

The core library (no simulator, no model zoo) is importable from here; names load on first use so that
`import gazereg` stays cheap:

>>> from gazereg import heatmaps_from_points, aggregate, PatchGeometry, patch_distribution, gaze_loss, AttentionProbe
"""

from __future__ import annotations

import importlib
from typing import Any

from gazereg.runtime.version import __version__

_EXPORTS = {
    "heatmaps_from_points": "gazereg.heatmaps",
    "AggregationConfig": "gazereg.aggregation",
    "aggregate": "gazereg.aggregation",
    "PatchGeometry": "gazereg.patches",
    "patch_distribution": "gazereg.patches",
    "WeightSchedule": "gazereg.losses",
    "gaze_kl": "gazereg.losses",
    "gaze_loss": "gazereg.losses",
    "AttentionProbe": "gazereg.attention.probe",
    "ProbeSpec": "gazereg.attention.probe",
}

__all__ = [*_EXPORTS, "__version__"]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'gazereg' has no attribute {name!r}")
