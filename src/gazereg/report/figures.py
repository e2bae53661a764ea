"""The experiment's figures: success bars with intervals, success-versus-steps curves, attention panels."""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any

import numpy as np

from gazereg.data.store import EpisodeStore
from gazereg.patches import grid_to_image
from gazereg.viz.overlay import overlay


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_success(table: dict[str, dict[str, dict[str, Any]]], path: Path) -> Path:
    plt = _plt()
    arms = list(table)
    conds = list(next(iter(table.values())))
    width = 0.8 / max(len(arms), 1)
    fig, ax = plt.subplots(figsize=(1.6 + 1.4 * len(conds), 3.2))
    for i, arm in enumerate(arms):
        x = np.arange(len(conds)) + (i - (len(arms) - 1) / 2) * width
        rates = [table[arm][c]["rate"] for c in conds]
        # clipped at 0: a Wilson bound can sit a rounding error on the wrong side of a rate of 0 or 1
        lo = [max(0.0, table[arm][c]["rate"] - table[arm][c]["ci95"][0]) for c in conds]
        hi = [max(0.0, table[arm][c]["ci95"][1] - table[arm][c]["rate"]) for c in conds]
        ax.bar(x, rates, width, yerr=[lo, hi], capsize=3, label=arm)
    ax.set_xticks(np.arange(len(conds)), conds, rotation=15)
    ax.set_ylim(0, 1)
    ax.set_ylabel("success rate (Wilson 95%)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_convergence(
    conv: dict[str, Any], losses: dict[str, list[tuple[int, float, float | None]]], path: Path
) -> Path:
    """Success vs steps (clean), training action loss, and each gaze arm's held-out KL to its own prior."""
    plt = _plt()
    arms = list(dict.fromkeys([*conv["arms"], *losses]))
    color = {arm: f"C{i}" for i, arm in enumerate(arms)}  # one colour per arm in every panel
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.2))
    for arm, c in conv["arms"].items():
        ci = np.array(c["ci95"])
        axes[0].plot(c["steps"], c["rates"], marker="o", label=arm, color=color[arm])
        axes[0].fill_between(c["steps"], ci[:, 0], ci[:, 1], alpha=0.15, color=color[arm])
    axes[0].set(xlabel="training step", ylabel="success (clean)", ylim=(0, 1), title="success vs steps")
    for arm, pts in losses.items():
        if not pts:
            continue
        s = [p[0] for p in pts]
        axes[1].plot(s, [p[1] for p in pts], label=arm, color=color[arm])
        kl = [(p[0], p[2]) for p in pts if p[2] is not None]
        if kl:
            axes[2].plot(*zip(*kl), label=arm, color=color[arm])
    axes[1].set(xlabel="training step", ylabel="action loss (L1, normalised)", title="training loss")
    axes[2].set(
        xlabel="training step", ylabel="KL(own prior || attention)", title="held-out KL to the arm's prior"
    )
    for ax in axes:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def attention_panels(
    store: EpisodeStore,
    maps_by_arm: dict[str, tuple[Any, dict[str, Any]]],
    gaze_prior: str | None,
    camera: str,
    frames: int,
) -> tuple[list[dict[str, Any]], list[str]]:
    """`plot_attention`'s panels and columns: `frames` frames spread evenly over the held-out frames the
    attention maps cover, each with the stored gaze prior (when named) and every arm's attention.

    maps_by_arm: {arm: (policy, maps)}, maps as `evaluation.alignment.attention_maps` returns them (the same
    frames for every arm): "episode_t" (N, 2) episode index and frame, "attention" (N, n_patches) on the
    policy's patch grid of `camera`, turned into (H, W) images of the frame's size."""
    any_maps = next(iter(maps_by_arm.values()))[1]
    ep_t = any_maps["episode_t"].numpy()
    rows = np.linspace(0, len(ep_t) - 1, frames + 2).round().astype(int)[1:-1]
    panels = []
    for r in rows:
        ep, t = int(ep_t[r, 0]), int(ep_t[r, 1])
        episode = store.read(ep, cameras=[camera])
        frame = np.asarray(episode.frames[camera][t])
        panel: dict[str, Any] = {"title": f"{episode.task} t={t}", "frame": frame}
        if gaze_prior:
            heat, _ = store.read_prior(gaze_prior, ep)
            panel["gaze prior"] = heat[t]
        for arm, (policy, maps) in maps_by_arm.items():
            panel[f"{arm} attention"] = grid_to_image(
                maps["attention"][r], policy.geometry(camera), frame.shape[:2]
            ).numpy()
        panels.append(panel)
    columns = (["gaze prior"] if gaze_prior else []) + [f"{arm} attention" for arm in maps_by_arm]
    return panels, columns


def plot_attention(panels: list[dict[str, Any]], columns: list[str], path: Path) -> Path:
    """panels: one row each: {"title": str, "frame": (H, W, 3) uint8, column: (H, W) heat or None}."""
    plt = _plt()
    cols = ["observation", *columns]
    fig, axes = plt.subplots(
        len(panels), len(cols), figsize=(2.1 * len(cols), 2.2 * len(panels)), squeeze=False
    )
    for i, row in enumerate(panels):
        for j, col in enumerate(cols):
            ax = axes[i, j]
            img = (
                row["frame"]
                if col == "observation" or row.get(col) is None
                else overlay(row["frame"], row[col])
            )
            ax.imshow(img)
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(col, fontsize=9)
        # long task names (LIBERO's) wrapped to the panel's height
        axes[i, 0].set_ylabel(textwrap.fill(row["title"].replace("_", " "), 32), fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def stack_figures(paths: list[Path], path: Path) -> Path:
    """The PNG figures `paths` one above the other in `path` (narrower ones padded white on the right): one
    attention figure of a pooled report from its folders', each showing its own arms."""
    plt = _plt()
    images = [plt.imread(p) for p in paths]  # (H, W, C) floats in [0, 1], C 3 or 4
    images = [np.dstack([im, np.ones(im.shape[:2])]) if im.shape[2] == 3 else im for im in images]
    width = max(im.shape[1] for im in images)
    padded = [np.pad(im, ((0, 0), (0, width - im.shape[1]), (0, 0)), constant_values=1.0) for im in images]
    path.parent.mkdir(parents=True, exist_ok=True)
    plt.imsave(path, np.concatenate(padded, axis=0))
    return path
