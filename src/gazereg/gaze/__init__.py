"""Gaze: heatmaps from points, temporal aggregation, gaze sources and the prior pipeline."""
