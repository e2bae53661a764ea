"""`LeRobotV3Dataset`: a local LeRobot v3.0 data set read episode by episode into store `Episode`s.

What goes where in the Episode is described in gazereg.data.formats.lerobot_v3 (the importer's module docstring).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gazereg.data.errors import DataImportError, ImportUsageError
from gazereg.data.formats.lerobot_v3.frames import VideoFrames, read_images
from gazereg.data.formats.lerobot_v3.metadata import (
    STANDARD_COLUMNS,
    DataFileCache,
    EpisodeMeta,
    camera_name,
    data_file,
    image_hw,
    read_episodes,
    read_info,
    read_tasks,
    rgb_cameras,
    to_numpy,
)
from gazereg.data.imports import check_finite, recorded_gaze
from gazereg.data.store import Episode


@dataclass
class _Rows:
    """One episode's rows of its data file, in frame order; `where` names them in errors."""

    table: Any
    where: str

    def __len__(self) -> int:
        return self.table.num_rows

    def column(self, name: str, required: bool = True) -> np.ndarray | None:
        if name not in self.table.column_names:
            if required:
                raise DataImportError(f"{self.where}: column {name!r} is missing")
            return None
        return to_numpy(self.table.column(name), f"{self.where}: column {name!r}")


class LeRobotV3Dataset:
    """Reads a local LeRobot v3.0 data set episode by episode (streaming: one data file and one video file per
    camera open at a time). `nonfinite_ok`: features whose NaN/inf values are imported as they are (NaN/inf in
    any other feature is refused with the column, the episode and the first bad row; the gaze column's NaN
    means no gaze)."""

    def __init__(self, root: str | Path, tolerance_s: float = 1e-4, nonfinite_ok: tuple[str, ...] = ()):
        self.root = Path(root)
        self.tolerance_s = tolerance_s
        self.nonfinite_ok = tuple(nonfinite_ok)
        self.info = read_info(self.root)
        self.fps = float(self.info["fps"])
        self.features: dict[str, dict[str, Any]] = self.info["features"]
        self.cameras: dict[str, str] = rgb_cameras(self.features)  # store name -> feature key
        self.video_keys = [k for k in self.cameras.values() if self.features[k]["dtype"] == "video"]
        self.tasks = read_tasks(self.root)
        self.episodes = read_episodes(self.root)
        self._data = DataFileCache()
        self._videos = VideoFrames(self.root, self.info, tolerance_s)

    def fingerprint(self) -> str:
        """Identifies the data set's schema (features and fps), not its path or size."""
        blob = json.dumps({"features": self.features, "fps": self.fps}, sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]

    def close(self) -> None:
        self._videos.close()
        self._data.close()

    def default_gaze_camera(self, cams: list[str]) -> str:
        for key in self.video_keys:
            if camera_name(key) in cams:
                return camera_name(key)
        if not cams:
            raise DataImportError(f"{self.root}: no camera to attach the gaze to")
        return cams[0]

    def gaze_camera(
        self, cams: list[str], gaze_key: str | None, gaze_camera: str | None = None
    ) -> str | None:
        """The imported camera the gaze column `gaze_key` refers to; None where the data set has no such column."""
        if not (gaze_key and gaze_key in self.features):
            if gaze_camera is not None:
                raise ImportUsageError(
                    f"{self.root}: --gaze-camera {gaze_camera} given but the data set has no gaze column {gaze_key!r}"
                )
            return None
        cam = gaze_camera or self.default_gaze_camera(cams)
        if cam not in cams:
            raise ImportUsageError(
                f"{self.root}: gaze camera {cam!r} is not among the imported cameras {cams}"
            )
        return cam

    # ----- one episode ---------------------------------------------------------------------------------
    def read_episode(
        self,
        index: int,
        cameras: list[str] | None = None,
        gaze_key: str | None = "gaze.point",
        gaze_camera: str | None = None,
        state_key: str = "observation.state",
        action_key: str = "action",
        rotate180: tuple[str, ...] = (),
    ) -> Episode:
        """One episode as a store Episode (see gazereg.data.formats.lerobot_v3 for what goes where)."""
        ep = self._episode(index)
        cams = self._cameras(cameras)
        rows = self._rows(ep, cams)
        timestamp = rows.column("timestamp")
        extras = _index_extras(rows, timestamp)
        state, action = _state_action(rows, state_key, action_key)
        frames = {cam: self._frames(ep, cam, rows, timestamp) for cam in cams}
        meta: dict[str, Any] = {"fps": self.fps, "lerobot_keys": {c: self.cameras[c] for c in cams}}
        gcam = self.gaze_camera(cams, gaze_key, gaze_camera)
        if gcam is not None:
            extras.update(_gaze_extras(rows, gaze_key, gcam, gcam in rotate180))
            meta["gaze"] = {"camera": gcam, "key": gaze_key}
        extras.update(self._feature_extras(rows, skip={state_key, action_key, gaze_key}))
        rotated = _rotate180(frames, rotate180)
        if rotated:
            meta["orientation_applied"] = dict.fromkeys(rotated, "rot180")
        meta["tasks"] = tasks = self._episode_tasks(ep, rows)
        task = tasks[0] if tasks else ""
        return Episode(
            task=task,
            instruction=task,
            frames=frames,
            state=state,
            action=action,
            extras=extras,
            meta=meta,
            index=index,
        )

    def _episode(self, index: int) -> EpisodeMeta:
        if index not in self.episodes:
            raise DataImportError(f"{self.root}: no episode {index} (it has {len(self.episodes)} episodes)")
        return self.episodes[index]

    def _cameras(self, cameras: list[str] | None) -> list[str]:
        cams = list(self.cameras) if cameras is None else list(cameras)
        for c in cams:
            if c not in self.cameras:
                raise ImportUsageError(f"{self.root}: no camera {c!r} (it has {sorted(self.cameras)})")
        return cams

    def _rows(self, ep: EpisodeMeta, cams: list[str]) -> _Rows:
        """The episode's rows of its data file, checked against the metadata and put in frame order."""
        path = data_file(self.root, self.info, ep)
        skip = frozenset(
            k for c, k in self.cameras.items() if c not in cams and self.features[k]["dtype"] == "image"
        )
        table = self._data.episode_rows(path, ep.index, skip)
        where = f"{path}, episode {ep.index}"
        if table is None:
            raise DataImportError(f"{where}: the data file has no rows of this episode")
        T = table.num_rows
        if ep.length != T:
            raise DataImportError(
                f"{where}: {T} frames in the data file but the episode metadata says length {ep.length}"
            )
        frm, to = ep.row.get("dataset_from_index"), ep.row.get("dataset_to_index")
        if frm is not None and to is not None and to - frm != T:
            raise DataImportError(f"{where}: {T} frames but dataset_from_index..to_index spans {to - frm}")
        return _in_frame_order(_Rows(table, where))

    def _frames(self, ep: EpisodeMeta, cam: str, rows: _Rows, timestamp: np.ndarray) -> np.ndarray:
        key = self.cameras[cam]
        ft = self.features[key]
        shape = image_hw(ft)
        if ft["dtype"] == "video":
            frames = self._videos.read(ep, key, timestamp, shape)
        else:
            frames = read_images(rows.table, key, self.root, rows.where, shape)
        if frames.shape[0] != len(rows):
            raise DataImportError(
                f"{rows.where}: camera {cam!r} has {frames.shape[0]} frames, expected {len(rows)}"
            )
        return frames

    def _feature_extras(self, rows: _Rows, skip: set[str | None]) -> dict[str, np.ndarray]:
        """Every other numeric per-frame feature of the data file, under its own key."""
        skip = {*STANDARD_COLUMNS, *skip, *self.cameras.values()}
        extras = {}
        for key, ft in self.features.items():
            if key in skip or ft.get("dtype") in ("video", "image", "string"):
                continue
            if key not in rows.table.column_names:
                continue
            try:
                arr = rows.column(key)
            except DataImportError:
                continue
            if arr.dtype.kind in "biuf" and arr.shape[0] == len(rows):
                extras[key] = check_finite(arr, f"{rows.where}: column {key!r}", key, self.nonfinite_ok)
        return extras

    def _episode_tasks(self, ep: EpisodeMeta, rows: _Rows) -> list[str]:
        """The episode's task strings: its metadata's, then those of its rows' task_index, each once."""
        tasks = list(ep.tasks)
        task_index = rows.column("task_index", required=False)
        if task_index is not None:
            tasks += [
                self.tasks[int(t)]
                for t in np.unique(task_index)
                if int(t) in self.tasks and self.tasks[int(t)] not in tasks
            ]
        return tasks


def _rotate180(frames: dict[str, np.ndarray], cameras: tuple[str, ...]) -> list[str]:
    """Turn the named cameras' frames by 180 degrees in place; returns the cameras turned."""
    turned = [c for c in cameras if c in frames]
    for c in turned:
        frames[c] = np.ascontiguousarray(frames[c][:, ::-1, ::-1])
    return turned


def _in_frame_order(rows: _Rows) -> _Rows:
    """The rows sorted by frame_index, which must run 0..T-1."""
    T = len(rows)
    frame_index = rows.column("frame_index")
    order = np.argsort(frame_index, kind="stable")
    ordered = frame_index[order]
    breaks = np.flatnonzero(ordered != np.arange(T))
    if breaks.size:
        k = int(breaks[0])
        raise DataImportError(
            f"{rows.where}: frame_index must run 0..{T - 1} but breaks after {k - 1}: expected {k}, got "
            f"{ordered[k]} (a missing or repeated frame)"
            if k
            else f"{rows.where}: frame_index must run 0..{T - 1} but starts at {ordered[0]}"
        )
    if np.array_equal(order, np.arange(T)):
        return rows
    return _Rows(rows.table.take(order), rows.where)


def _index_extras(rows: _Rows, timestamp: np.ndarray) -> dict[str, np.ndarray]:
    """The data set's frame index, timestamp and (where present) global index of every frame."""
    extras = {
        "lerobot.frame_index": np.arange(len(rows), dtype=np.int64),  # _in_frame_order checked it is 0..T-1
        "lerobot.timestamp": timestamp.astype(np.float32),
    }
    index = rows.column("index", required=False)
    if index is not None:
        extras["lerobot.index"] = index.astype(np.int64)
    return extras


def _state_action(rows: _Rows, state_key: str, action_key: str) -> tuple[np.ndarray, np.ndarray]:
    """(T, d) float32 state ((T, 0) where the data set has none) and action."""
    T = len(rows)
    action = rows.column(action_key).astype(np.float32).reshape(T, -1)
    state = rows.column(state_key, required=False)
    state = np.zeros((T, 0), np.float32) if state is None else state.astype(np.float32).reshape(T, -1)
    return state, action


def _gaze_extras(rows: _Rows, key: str, camera: str, rotate180: bool) -> dict[str, np.ndarray]:
    """The recorded gaze column as the `recorded` gaze source's extras of `camera`."""
    uv, valid = recorded_gaze(rows.column(key), f"{rows.where}: gaze column {key!r}", rotate180)
    return {f"gaze_uv.{camera}": uv, f"gaze_valid.{camera}": valid}
