"""LeRobot v3.0 data sets in, without the lerobot package (pyarrow + PyAV only).

Import (`gazereg import lerobot --root PATH --out STORE [--gaze-camera front]`):

    <root>/meta/info.json                     features, fps, data_path / video_path templates
    <root>/meta/episodes/chunk-*/file-*.parquet   one row per episode: length, tasks, data/{chunk,file}_index,
                                              dataset_{from,to}_index, videos/<key>/{chunk,file}_index,
                                              videos/<key>/{from,to}_timestamp
    <root>/meta/tasks.parquet                 task_index -> task string
    <root>/data/chunk-*/file-*.parquet        one row per frame (several episodes per file)
    <root>/videos/<key>/chunk-*/file-*.mp4    one stream per camera (several episodes per file)

Each LeRobot episode becomes the store episode with the same index (`episode_index`), so an interrupted
import resumes where it stopped. What lands in the store:
  - frames.<camera>: "video" features decoded with PyAV at `from_timestamp + timestamp` (gazereg.data.formats.video),
    "image" features decoded from the PNG/JPEG bytes in the data parquet; `camera` is the feature key without
    its `observation.images.` prefix (`observation.images.front` -> `front`). Depth maps are skipped.
  - state = `observation.state` ((T, 0) if the data set has none), action = `action`.
  - task = instruction = the episode's (first) task string; meta["tasks"] lists all of them.
  - extras["gaze_uv.<camera>"] (T, 2) float32 and extras["gaze_valid.<camera>"] (T,) bool from the gaze column
    (`gaze.point`, (u, v) normalised, u right, v down; NaN = no gaze), which is the `recorded` gaze source's
    input. The camera the gaze refers to is `gaze_camera` (default: the first video camera).
  - extras["lerobot.frame_index" | "lerobot.index" | "lerobot.timestamp"], and every other numeric per-frame
    feature under its own key (NaN/inf in it is refused unless `nonfinite_ok` names it; in state and action
    always); meta["source"] records the data set, its episode_index and the settings, meta["fps"] the frame
    rate.

Orientation: frames are stored as the data set holds them (LeRobot data sets are upright; LeRobot's LIBERO
conversions were already rotated), and gaze stays in that frame. `rotate180` (none | all | comma-separated
cameras) turns cameras by 180 degrees at import (frames and that camera's gaze, u -> 1-u, v -> 1-v); it is
recorded in meta["orientation_applied"] and undone by the priors export, so a sidecar for a LeRobot-imported
episode is always in the data set's own frame.

Modules: gazereg.data.formats.lerobot_v3.metadata (meta/ and the data parquet files), gazereg.data.formats.lerobot_v3.frames
(video and image frames), gazereg.data.formats.lerobot_v3.dataset (`LeRobotV3Dataset`: one episode at a time), and
this one (the import). The priors go back out as a sidecar next to the data set: gazereg.data.formats.lerobot_v3.export
(`export_priors_lerobot`, `read_priors_lerobot`), or as features gaze.<camera>.heatmap / gaze.<camera>.valid of a
new data set version that `lerobot.datasets.LeRobotDataset` loads: gazereg.data.formats.lerobot_v3.gaze_feature
(`write_gaze_dataset`, `gazereg import write-gaze`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gazereg.data.errors import ImportUsageError
from gazereg.data.formats.lerobot_v3.dataset import LeRobotV3Dataset
from gazereg.data.imports import SourceEpisode, import_into, rotated_cameras
from gazereg.data.store import Episode
from gazereg.runtime.config import parse


@dataclass(frozen=True)
class LeRobotImportConfig:
    root: Path = Path("data/lerobot")
    """LeRobot v3.0 data set folder (holds meta/info.json)"""
    out: Path = Path("data/demos")
    """episode store to write (created if missing; episodes already there are skipped)"""
    cameras: tuple[str, ...] = ()
    """store camera names to import (e.g. front wrist); default: every RGB image/video feature"""
    gaze_key: str = "gaze.point"
    """per-frame gaze column, (u, v) normalised; ignored when the data set has none"""
    gaze_camera: str | None = None
    """camera the gaze refers to (default: the first video camera)"""
    state_key: str = "observation.state"
    action_key: str = "action"
    episodes: tuple[int, ...] = ()
    """episode_index values to import; default: all"""
    rotate180: str = "none"
    """cameras to turn by 180 degrees at import (frames and gaze): none | all | comma-separated names;
    recorded in meta["orientation_applied"] and undone on export"""
    tolerance_s: float = 1e-4
    """max difference between a frame's video time and from_timestamp + timestamp"""
    nonfinite_ok: tuple[str, ...] = ()
    """features whose NaN/inf values are imported as they are (by default NaN/inf outside the gaze column is
    refused, naming the column and the first bad row)"""
    progress: bool = True


def _selected(wanted: tuple[Any, ...], have: dict[Any, Any], what: str, has: str, root: Path) -> list[Any]:
    """The `wanted` names (all of `have` when none are given), refusing any that `have` lacks."""
    chosen = list(wanted) or list(have)
    unknown = [x for x in chosen if x not in have]
    if unknown:
        raise ImportUsageError(f"{root}: no {what} {unknown[:10]}{has}")
    return chosen


def plan_lerobot(cfg: LeRobotImportConfig, dataset: LeRobotV3Dataset) -> list[SourceEpisode]:
    """The episodes to import, each with its identity (compared on resume) and its loader; checks the settings
    against the data set first, so a bad option fails before anything is written."""
    root, have_cams, have_eps = dataset.root, dataset.cameras, dataset.episodes
    cams = _selected(cfg.cameras, have_cams, "camera(s)", f"; it has {sorted(have_cams)}", root)
    rotate = rotated_cameras(cfg.rotate180, cams, where=f" from {root}")
    gaze_cam = dataset.gaze_camera(cams, cfg.gaze_key, cfg.gaze_camera)
    gaze_key = cfg.gaze_key if gaze_cam is not None else None
    wanted = _selected(cfg.episodes, have_eps, "episode(s)", f" (it has {len(have_eps)})", root)
    settings = {
        "cameras": cams,
        "gaze_camera": gaze_cam,
        "gaze_key": gaze_key,
        "state_key": cfg.state_key,
        "action_key": cfg.action_key,
        "rotate180": rotate,
    }
    source = {"format": "lerobot_v3", "root": str(root.resolve()), "dataset": dataset.fingerprint()}

    def load(e: int) -> Episode:
        return dataset.read_episode(e, cams, gaze_key, gaze_cam, cfg.state_key, cfg.action_key, tuple(rotate))

    items = []
    for e in wanted:
        length = have_eps[e].length
        identity = {**source, "episode_index": e, "episode": e, "length": length, "settings": settings}
        items.append(SourceEpisode(index=e, identity=identity, load=lambda e=e: load(e), length=length))
    return items


def import_lerobot(cfg: LeRobotImportConfig) -> dict[str, Any]:
    """Import (or resume importing) a LeRobot v3.0 data set into cfg.out; returns counts and throughput."""
    dataset = LeRobotV3Dataset(cfg.root, tolerance_s=cfg.tolerance_s, nonfinite_ok=cfg.nonfinite_ok)
    items = plan_lerobot(cfg, dataset)
    try:
        report = import_into(
            cfg.out, items, total=len(items), desc=f"import {dataset.root.name}", progress=cfg.progress
        )
    finally:
        dataset.close()
    return report


def import_main(argv: list[str]) -> int:
    cfg = parse(
        {"default": LeRobotImportConfig},
        argv,
        prog="gazereg import lerobot",
        description=__doc__.split("\n\n")[0],
    )
    report = import_lerobot(cfg)
    print(json.dumps({"store": str(cfg.out), **report}))
    return 0


__all__ = [
    "LeRobotImportConfig",
    "LeRobotV3Dataset",
    "import_lerobot",
    "import_main",
    "plan_lerobot",
]
