"""gazevla: gaze-regularized Vision-Language-Action policies.

The core library (no simulator, no model zoo) is importable from here:

>>> from gazevla import heatmaps_from_points, aggregate, PatchGeometry, patch_distribution, gaze_kl, AttentionProbe
"""

__version__ = "0.1.0"

from gazevla.attention.probe import AttentionProbe, ProbeSpec
from gazevla.gaze.aggregation import AggregationConfig, aggregate
from gazevla.gaze.heatmaps import heatmaps_from_points
from gazevla.losses import GazeLossConfig, WeightSchedule, gaze_kl, gaze_loss
from gazevla.patches import PatchGeometry, patch_distribution

__all__ = [
    "AggregationConfig",
    "AttentionProbe",
    "GazeLossConfig",
    "PatchGeometry",
    "ProbeSpec",
    "WeightSchedule",
    "aggregate",
    "gaze_kl",
    "gaze_loss",
    "heatmaps_from_points",
    "patch_distribution",
    "__version__",
]
