"""Figures: episode strips with gaze (`gazevla.viz.strip`), heatmap overlays (`gazevla.viz.overlay`).

Command line: `gazevla viz strip --store PATH --episode 0 --camera corner2 --out strip.png`.
"""
