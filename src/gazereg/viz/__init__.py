"""Figures: episode strips with gaze (`gazereg.viz.strip`), heatmap overlays (`gazereg.viz.overlay`).

Command line: `gazereg viz strip --store PATH --episode 0 --camera corner2 --out strip.png`.
"""
