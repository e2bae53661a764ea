"""An episode strip: N frames of one camera with the gaze heatmap and point drawn over them, and a timeline.

    from gazereg.viz.strip import draw_strip
    draw_strip(episode, "corner2", heatmaps=heat, valid=valid, points=trace.uv, out="strip.png")

Top row: the frames (evenly spaced over the episode unless `frames` picks them), each with the heatmap
blended in (opacity follows the heat), the gaze point as a white cross, and, when the episode has them, the
projected object (cyan circle) and goal (magenta square) as thin outlines. Bottom: a timeline of the episode
with the gaze target, the gripper's contact and grasp events, and the shown frames.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gazereg.data.store import Episode
from gazereg.runtime.io import atomic_path
from gazereg.viz.overlay import overlay


def pick_frames(length: int, n: int) -> list[int]:
    """`n` frame indices spread evenly over an episode of `length` frames, first and last included."""
    if length <= 0:
        raise ValueError("the episode has no frames")
    n = max(1, min(n, length))
    return sorted({int(round(x)) for x in np.linspace(0, length - 1, n)})


def _pyplot() -> Any:
    """matplotlib.pyplot on the non-interactive Agg backend (unless one was chosen already), imported lazily."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def draw_strip(
    episode: Episode,
    camera: str,
    heatmaps: np.ndarray | None = None,
    valid: np.ndarray | None = None,
    points: np.ndarray | None = None,
    frames: Sequence[int] | None = None,
    n_frames: int = 8,
    target: np.ndarray | None = None,
    target_names: Sequence[str] = (),
    title: str | None = None,
    panel_inches: float = 1.9,
    out: str | Path | None = None,
) -> Any:
    """Draw the strip; returns the matplotlib Figure (written to `out` as PNG when given, atomically).

    heatmaps: (T, h, w) per-frame gaze maps (any grid; stretched over the image), valid: (T,) bool.
    points: (T, 2) normalised (u, v) gaze points (NaN: none). target: (T,) int index into target_names.
    frames: the frame indices to show (default: `n_frames` spread evenly). panel_inches: one frame's size.
    """
    plt = _pyplot()
    idx = _check_inputs(
        episode, camera, frames, n_frames, heatmaps=heatmaps, valid=valid, points=points, target=target
    )
    T = len(episode.frames[camera])
    names = target_names if target is not None else ()
    n = len(idx)
    fig = plt.figure(figsize=(panel_inches * n, panel_inches * 1.45 + 0.35), dpi=100)
    gs = fig.add_gridspec(2, n, height_ratios=[panel_inches, 0.42 * panel_inches], hspace=0.25, wspace=0.04)
    for j, t in enumerate(idx):
        _draw_frame(fig.add_subplot(gs[0, j]), episode, camera, t, heatmaps, valid, points, target, names)
    _draw_timeline(fig.add_subplot(gs[1, :]), episode, T, idx, valid, target, names)
    fig.suptitle(
        title or f"episode {episode.index}: {episode.task} ({camera}, {T} frames)", fontsize=9, y=0.995
    )
    if out is not None:
        with atomic_path(Path(out)) as tmp:
            fig.savefig(tmp, format="png", bbox_inches="tight")
    return fig


def _check_inputs(
    episode: Episode, camera: str, frames: Sequence[int] | None, n_frames: int, **per_frame: np.ndarray | None
) -> list[int]:
    """The frame indices to draw, after checking the camera exists and every per-frame array has T entries."""
    if camera not in episode.frames:
        raise KeyError(f"episode {episode.index} has no camera {camera!r}; cameras: {sorted(episode.frames)}")
    T = len(episode.frames[camera])
    for name, arr in per_frame.items():
        if arr is not None and len(arr) != T:
            raise ValueError(f"{name} has {len(arr)} frames, the episode has {T}")
    idx = list(frames) if frames is not None else pick_frames(T, n_frames)
    bad = [i for i in idx if not 0 <= i < T]
    if bad:
        raise ValueError(f"frames {bad} are outside the episode (0..{T - 1})")
    return idx


def _draw_frame(
    ax: Any,
    episode: Episode,
    camera: str,
    t: int,
    heatmaps: np.ndarray | None,
    valid: np.ndarray | None,
    points: np.ndarray | None,
    target: np.ndarray | None,
    target_names: Sequence[str],
) -> None:
    """One panel: frame `t` with its heatmap blended in, the projected object and goal, and the gaze point."""
    img = np.asarray(episode.frames[camera][t])
    H, W = img.shape[:2]
    ok = True if valid is None else bool(valid[t])
    if heatmaps is not None and ok and float(np.asarray(heatmaps[t]).max()) > 0:
        img = overlay(img, np.asarray(heatmaps[t], dtype=np.float64))
    ax.imshow(img, extent=(0, W, H, 0), interpolation="nearest")
    for key, marker, colour in (("obj_uv", "o", "cyan"), ("goal_uv", "s", "magenta")):
        uv = episode.extras.get(f"{key}.{camera}")
        if uv is not None and np.isfinite(uv[t]).all():
            ax.plot(uv[t, 0] * W, uv[t, 1] * H, marker, ms=9, mfc="none", mec=colour, mew=0.9)
    if points is not None and np.isfinite(points[t]).all() and ok:
        ax.plot(points[t, 0] * W, points[t, 1] * H, "+", ms=11, color="white", mew=2.0)
        ax.plot(points[t, 0] * W, points[t, 1] * H, "+", ms=9, color="black", mew=0.8)
    label = f"t={t}"
    if target is not None and len(target_names):
        label += f" {target_names[int(target[t])]}"
    if not ok:
        label += " (no gaze)"
    ax.set_title(label, fontsize=8, pad=2)
    ax.set_xlim(0, W)
    ax.set_ylim(H, 0)
    ax.axis("off")


def _draw_timeline(
    tl: Any,
    episode: Episode,
    T: int,
    idx: Sequence[int],
    valid: np.ndarray | None,
    target: np.ndarray | None,
    target_names: Sequence[str],
) -> None:
    """The episode's timeline: gaze target (and frames without gaze), contact and grasp, the shown frames."""
    rows = []
    if target is not None and len(target_names):
        colours = _pyplot().get_cmap("tab10")
        for k, name in enumerate(target_names):
            tl.broken_barh(
                _runs(np.asarray(target) == k),
                (2.1, 0.8),
                color=colours(k),
                alpha=0.85,
                label=f"gaze: {name}",
            )
        rows.append((2.5, "gaze target"))
    if valid is not None and not np.asarray(valid, dtype=bool).all():
        tl.broken_barh(
            _runs(~np.asarray(valid, dtype=bool)), (2.1, 0.8), color="grey", alpha=0.9, label="no gaze"
        )
    for y, key, colour in ((1.5, "contact", "tab:orange"), (0.5, "grasp", "tab:red")):
        if key in episode.extras:
            tl.broken_barh(
                _runs(np.asarray(episode.extras[key]).astype(bool)), (y - 0.4, 0.8), color=colour, alpha=0.85
            )
            rows.append((y, key))
    for t in idx:
        tl.axvline(t, color="black", lw=0.6, alpha=0.5)
    tl.set_xlim(-0.5, T - 0.5)
    tl.set_ylim(0, 3)
    tl.set_yticks([y for y, _ in rows], [name for _, name in rows], fontsize=7)
    tl.tick_params(axis="x", labelsize=7)
    tl.set_xlabel("frame", fontsize=7, labelpad=1)
    if target is not None and len(target_names):
        tl.legend(
            fontsize=6, loc="upper right", ncol=len(target_names) + 1, frameon=False, bbox_to_anchor=(1, 1.45)
        )


def _runs(mask: np.ndarray) -> list[tuple[float, float]]:
    """(start - 0.5, length) of each run of True in a 1-D mask: bars that cover whole frames."""
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return [(float(a) - 0.5, float(b - a)) for a, b in zip(edges[::2], edges[1::2])]
