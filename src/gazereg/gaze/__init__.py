"""Gaze: gaze sources, the prior pipeline and the GLC video gaze estimator (above data/; heatmaps from points
and their temporal aggregation are core modules, `gazereg.heatmaps` and `gazereg.aggregation`)."""
