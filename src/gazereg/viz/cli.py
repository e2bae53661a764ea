"""`gazereg viz`: figures of episodes and their gaze.

    gazereg viz strip --store runs/smoke/demos --episode 0 --camera corner2 --out strip.png
    gazereg viz strip --store runs/smoke/demos --episode 1000 --prior visuomotor --out strip.png
    gazereg viz strip --store ... --source visuomotor --source-params lead_time_s=0.5 jitter=0 --frames 10

`strip` draws frames of one episode with a gaze heatmap and point over them (by default from the
`visuomotor` source computed on the fly; `--prior NAME` shows a prior stored in the episode store instead).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gazereg.data.store import EpisodeStore
from gazereg.gaze.sources import make_gaze_source, parse_source_params
from gazereg.runtime.config import parse
from gazereg.runtime.errors import UsageError
from gazereg.runtime.subcommands import Subcommands
from gazereg.viz.strip import draw_strip


@dataclass(frozen=True)
class StripConfig:
    store: Path = Path("runs/smoke/demos")
    """episode store"""
    episode: int = 0
    """episode index in the store"""
    camera: str = ""
    """camera to draw (default: the episode's first)"""
    out: Path = Path("strip.png")
    """PNG to write"""
    frames: int = 8
    """number of frames, spread evenly over the episode"""
    source: str = "visuomotor"
    """gaze source computed on the fly (ignored with --prior)"""
    source_params: tuple[str, ...] = ()
    """source parameters as key=value (values parsed as JSON when possible)"""
    prior: str = ""
    """draw this stored prior instead of a source"""
    heatmap_size: int = 64
    """heatmap grid (cells per side) for an on-the-fly source"""


def strip(cfg: StripConfig) -> Path:

    store = EpisodeStore(cfg.store)
    if cfg.episode not in store:
        have = store.indices()
        raise UsageError(
            f"--episode: no episode {cfg.episode} in {cfg.store}; it has {len(have)}: "
            f"{have[:20]}{' ...' if len(have) > 20 else ''}"
        )
    ep = store.read(cfg.episode)
    camera = cfg.camera or next(iter(ep.frames))
    if camera not in ep.frames:
        raise UsageError(
            f"--camera: episode {cfg.episode} has no camera {camera!r}; cameras: {sorted(ep.frames)}"
        )
    points = target = None
    names: tuple[str, ...] = ()
    if cfg.prior:
        heat, valid = store.read_prior(cfg.prior, cfg.episode)
        label = f"prior {cfg.prior}"
    else:
        source = make_gaze_source(parse_source_params(cfg.source, cfg.source_params))
        if hasattr(source, "bind"):
            source.bind(store)
        heat, valid = source(ep, camera, (cfg.heatmap_size, cfg.heatmap_size))
        label = f"source {cfg.source}"
        if hasattr(source, "trace"):
            tr = source.trace(ep, camera)
            points, target, names = tr.uv, tr.target, tr.targets
    if points is None:  # mark the heatmap's peak
        flat = np.asarray(heat).reshape(len(heat), -1)
        h, w = np.asarray(heat).shape[1:]
        peak = flat.argmax(1)
        points = np.stack([(peak % w + 0.5) / w, (peak // w + 0.5) / h], axis=1).astype(np.float32)
        points[~np.asarray(valid, dtype=bool)] = np.nan
    fig = draw_strip(
        ep,
        camera,
        heatmaps=heat,
        valid=valid,
        points=points,
        target=target,
        target_names=names,
        n_frames=cfg.frames,
        title=f"episode {cfg.episode}: {ep.task} - {ep.instruction} ({camera}, {label})",
        out=cfg.out,
    )
    import matplotlib.pyplot as plt

    plt.close(fig)
    return Path(cfg.out)


def strip_main(argv: list[str]) -> int:

    cfg = parse(
        {"default": StripConfig}, argv, prog="gazereg viz strip", description=__doc__.split("\n\n")[0]
    )
    print(f"wrote {strip(cfg)}")
    return 0


COMMANDS = Subcommands(
    prog="gazereg viz",
    synopsis="<figure> [options]",
    commands={
        "strip": ("gazereg.viz.cli:strip_main", "frames of an episode with its gaze heatmap and point")
    },
    heading="figures:",
    noun="figure",
    width=8,
)


def main(argv: list[str] | None = None) -> int:
    return COMMANDS.main(argv)


if __name__ == "__main__":
    raise SystemExit(main())
