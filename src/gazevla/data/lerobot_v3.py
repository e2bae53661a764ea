"""LeRobot v3.0 data sets in, without the lerobot package (pyarrow + PyAV only).

Import (`gazevla import lerobot --root PATH --out STORE [--gaze-camera front]`):

    <root>/meta/info.json                     features, fps, data_path / video_path templates
    <root>/meta/episodes/chunk-*/file-*.parquet   one row per episode: length, tasks, data/{chunk,file}_index,
                                              dataset_{from,to}_index, videos/<key>/{chunk,file}_index,
                                              videos/<key>/{from,to}_timestamp
    <root>/meta/tasks.parquet                 task_index -> task string
    <root>/data/chunk-*/file-*.parquet        one row per frame (several episodes per file)
    <root>/videos/<key>/chunk-*/file-*.mp4    one stream per camera (several episodes per file)

Each LeRobot episode becomes the store episode with the same index (`episode_index`), so an interrupted
import resumes where it stopped. What lands in the store:
  - frames.<camera>: "video" features decoded with PyAV at `from_timestamp + timestamp` (gazevla.data.video),
    "image" features decoded from the PNG/JPEG bytes in the data parquet; `camera` is the feature key without
    its `observation.images.` prefix (`observation.images.front` -> `front`). Depth maps are skipped.
  - state = `observation.state` ((T, 0) if the data set has none), action = `action`.
  - task = instruction = the episode's (first) task string; meta["tasks"] lists all of them.
  - extras["gaze_uv.<camera>"] (T, 2) float32 and extras["gaze_valid.<camera>"] (T,) bool from the gaze column
    (`gaze.point`, (u, v) normalised, u right, v down; NaN = no gaze), which is the `recorded` gaze source's
    input. The camera the gaze refers to is `gaze_camera` (default: the first video camera).
  - extras["lerobot.frame_index" | "lerobot.index" | "lerobot.timestamp"], and every other numeric per-frame
    feature under its own key; meta["source"] records the data set, its episode_index and the settings,
    meta["fps"] the frame rate.

Orientation: frames are stored as the data set holds them (LeRobot data sets are upright; LeRobot's LIBERO
conversions were already rotated), and gaze stays in that frame. `rotate180` (none | all | comma-separated
cameras) turns cameras by 180 degrees at import (frames and that camera's gaze, u -> 1-u, v -> 1-v); it is
recorded in meta["orientation_applied"] and undone by the priors export, so a sidecar for a LeRobot-imported
episode is always in the data set's own frame.

The priors go back out as a sidecar next to the data set: gazevla.data.lerobot_export
(`export_priors_lerobot`, `read_priors_lerobot`; re-exported here).
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gazevla.data.importers import (
    DataImportError,
    SourceEpisode,
    recorded_gaze,
    require_pyarrow,
    rotated_cameras,
    write_episodes,
)
from gazevla.data.lerobot_export import (  # re-exported: the priors sidecar used to live here
    SIDECAR_FORMAT,
    SIDECAR_VERSION,
    ExportPriorsConfig,
    LeRobotPriors,
    export_main,
    export_priors_lerobot,
    read_priors_lerobot,
)
from gazevla.data.store import Episode, EpisodeStore
from gazevla.data.video import DecodeError, VideoFile, decode_image

log = logging.getLogger(__name__)

_STANDARD = ("timestamp", "frame_index", "episode_index", "index", "task_index")


def camera_name(key: str) -> str:
    """Store camera name of a LeRobot image feature key: `observation.images.front` -> `front`."""
    for prefix in ("observation.images.", "observation.image.", "observation."):
        if key.startswith(prefix) and len(key) > len(prefix):
            key = key[len(prefix) :]
            break
    return key.replace("/", "_")


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
    progress: bool = True


@dataclass
class _EpisodeMeta:
    index: int
    length: int
    tasks: list[str]
    row: dict[str, Any]


class LeRobotV3Dataset:
    """Reads a local LeRobot v3.0 data set episode by episode (streaming: one data file and one video file per
    camera open at a time)."""

    def __init__(self, root: str | Path, tolerance_s: float = 1e-4):
        self.root = Path(root)
        self.tolerance_s = tolerance_s
        info_path = self.root / "meta" / "info.json"
        if not info_path.exists():
            raise DataImportError(f"{self.root} is not a LeRobot data set: {info_path} does not exist")
        try:
            self.info = json.loads(info_path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise DataImportError(f"{info_path} is not valid JSON: {e}") from e
        version = str(self.info.get("codebase_version", "?"))
        if not version.startswith("v3"):
            raise DataImportError(
                f"{info_path}: codebase_version {version}; only LeRobot v3.x data sets are supported (convert v2.x with lerobot's converter)"
            )
        for k in ("features", "fps", "data_path"):
            if k not in self.info:
                raise DataImportError(f"{info_path} has no {k!r}")
        self.fps = float(self.info["fps"])
        self.features: dict[str, dict[str, Any]] = self.info["features"]
        self.cameras: dict[str, str] = {}  # store name -> feature key
        self.video_keys: list[str] = []
        for key, ft in self.features.items():
            if ft.get("dtype") not in ("video", "image"):
                continue
            if (ft.get("info") or {}).get("is_depth_map") or (
                len(ft.get("shape", [])) == 3 and 3 not in (ft["shape"][0], ft["shape"][-1])
            ):
                log.info("skipping %s: not an RGB camera", key)
                continue
            self.cameras[camera_name(key)] = key
            if ft["dtype"] == "video":
                self.video_keys.append(key)
        self.tasks = self._read_tasks()
        self.episodes = self._read_episodes()
        self._table_file: tuple[Path, frozenset[str]] | None = None
        self._table: Any = None
        self._rows: dict[int, np.ndarray] = {}
        self._videos: dict[str, VideoFile] = {}

    # ----- metadata ------------------------------------------------------------------------------------
    def fingerprint(self) -> str:
        """Identifies the data set's schema (features and fps), not its path or size."""
        blob = json.dumps({"features": self.features, "fps": self.fps}, sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]

    def _read_parquet(self, path: Path, what: str, columns: list[str] | None = None) -> Any:
        _, pq = require_pyarrow()
        if not path.exists():
            raise DataImportError(f"{what}: {path} does not exist")
        try:
            return pq.read_table(path, columns=columns)
        except Exception as e:  # ArrowInvalid, OSError, thrift errors on corrupt files
            raise DataImportError(
                f"{what}: {path} could not be read (corrupt or truncated parquet?): {e}"
            ) from e

    def _read_tasks(self) -> dict[int, str]:
        path = self.root / "meta" / "tasks.parquet"
        if not path.exists():
            return {}
        t = self._read_parquet(path, "task table")
        if "task_index" not in t.column_names or "task" not in t.column_names:
            raise DataImportError(f"{path} must have columns task_index and task, has {t.column_names}")
        return {
            int(i): str(s) for i, s in zip(t.column("task_index").to_pylist(), t.column("task").to_pylist())
        }

    def _read_episodes(self) -> dict[int, _EpisodeMeta]:
        files = sorted((self.root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
        if not files:
            raise DataImportError(f"{self.root}: no episode metadata (meta/episodes/chunk-*/file-*.parquet)")
        _, pq = require_pyarrow()
        out: dict[int, _EpisodeMeta] = {}
        for path in files:
            try:
                names = pq.read_schema(path).names
            except Exception as e:
                raise DataImportError(
                    f"episode metadata: {path} could not be read (corrupt or truncated parquet?): {e}"
                ) from e
            cols = [c for c in names if not c.startswith("stats/")]
            for row in self._read_parquet(path, "episode metadata", cols).to_pylist():
                for k in ("episode_index", "length"):
                    if row.get(k) is None:
                        raise DataImportError(f"episode metadata {path}: a row has no {k!r}: {row}")
                e = int(row["episode_index"])
                tasks = [str(t) for t in (row.get("tasks") or [])]
                out[e] = _EpisodeMeta(e, int(row["length"]), tasks, row)
        return dict(sorted(out.items()))

    # ----- data files ----------------------------------------------------------------------------------
    def _data_file(self, ep: _EpisodeMeta) -> Path:
        try:
            rel = self.info["data_path"].format(
                chunk_index=int(ep.row["data/chunk_index"]), file_index=int(ep.row["data/file_index"])
            )
        except (KeyError, TypeError) as e:
            raise DataImportError(
                f"episode metadata of episode {ep.index} has no data/chunk_index or data/file_index"
            ) from e
        return self.root / rel

    def _load_table(self, path: Path, episode: int, skip: frozenset[str] = frozenset()) -> None:
        """Load one data file (without the image columns of cameras not imported) and index its episodes."""
        if self._table_file == (path, skip):
            return
        self._table = None
        self._table_file = None
        _, pq = require_pyarrow()
        columns = None
        if skip and path.exists():
            try:
                columns = [c for c in pq.read_schema(path).names if c not in skip]
            except Exception as e:
                raise DataImportError(
                    f"episode {episode} data: {path} could not be read (corrupt or truncated parquet?): {e}"
                ) from e
        table = self._read_parquet(path, f"episode {episode} data", columns)
        if "episode_index" not in table.column_names:
            raise DataImportError(f"episode {episode} data: {path} has no episode_index column")
        ep_col = table.column("episode_index").to_numpy()
        order = np.argsort(ep_col, kind="stable")
        uniq, starts = np.unique(ep_col[order], return_index=True)
        ends = [*starts[1:], len(order)]
        self._rows = {int(u): order[s:e] for u, s, e in zip(uniq, starts, ends)}
        self._table, self._table_file = table, (path, skip)

    def _video(self, key: str, path: Path, episode: int) -> VideoFile:
        vf = self._videos.get(key)
        if vf is not None and vf.path == path:
            return vf
        if vf is not None:
            vf.close()
            del self._videos[key]
        if not path.exists():
            raise DataImportError(
                f"episode {episode}: video of camera {camera_name(key)!r} ({key}) is missing: {path} does not exist"
            )
        try:
            vf = VideoFile(path, tolerance_s=self.tolerance_s)
        except DecodeError as e:
            raise DataImportError(f"episode {episode}, camera {camera_name(key)!r}: {e}") from e
        self._videos[key] = vf
        return vf

    def close(self) -> None:
        for vf in self._videos.values():
            vf.close()
        self._videos.clear()
        self._table = self._table_file = None

    # ----- episodes ------------------------------------------------------------------------------------
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
        """One episode as a store Episode (see the module docstring for what goes where)."""
        if index not in self.episodes:
            raise DataImportError(f"{self.root}: no episode {index} (it has {len(self.episodes)} episodes)")
        ep = self.episodes[index]
        cams = list(self.cameras) if cameras is None else list(cameras)
        for c in cams:
            if c not in self.cameras:
                raise DataImportError(f"{self.root}: no camera {c!r} (it has {sorted(self.cameras)})")
        path = self._data_file(ep)
        skip = frozenset(
            k for c, k in self.cameras.items() if c not in cams and self.features[k]["dtype"] == "image"
        )
        self._load_table(path, index, skip)
        table = self._table
        rows = self._rows.get(index)
        where = f"{path}, episode {index}"
        if rows is None:
            raise DataImportError(f"{where}: the data file has no rows of this episode")
        T = len(rows)
        if ep.length != T:
            raise DataImportError(
                f"{where}: {T} frames in the data file but the episode metadata says length {ep.length}"
            )
        frm, to = ep.row.get("dataset_from_index"), ep.row.get("dataset_to_index")
        if frm is not None and to is not None and to - frm != T:
            raise DataImportError(f"{where}: {T} frames but dataset_from_index..to_index spans {to - frm}")
        sub = table.take(rows)

        def column(name: str, required: bool = True) -> np.ndarray | None:
            if name not in sub.column_names:
                if required:
                    raise DataImportError(f"{where}: column {name!r} is missing")
                return None
            return _to_numpy(sub.column(name), f"{where}: column {name!r}")

        frame_index = column("frame_index")
        order = np.argsort(frame_index, kind="stable")
        if not np.array_equal(frame_index[order], np.arange(T)):
            raise DataImportError(f"{where}: frame_index is not 0..{T - 1} (got {frame_index[order][:5]}...)")
        if not np.array_equal(order, np.arange(T)):
            sub = sub.take(order)
            frame_index = frame_index[order]
        timestamp = column("timestamp")
        gidx = column("index", required=False)
        action = column(action_key).astype(np.float32).reshape(T, -1)
        state = column(state_key, required=False)
        state = np.zeros((T, 0), np.float32) if state is None else state.astype(np.float32).reshape(T, -1)

        frames: dict[str, np.ndarray] = {}
        for cam in cams:
            key = self.cameras[cam]
            ft = self.features[key]
            shape = _image_hw(ft)
            if ft["dtype"] == "video":
                frames[cam] = self._read_video(ep, key, timestamp, shape)
            else:
                frames[cam] = self._read_images(sub, key, where, shape)
            if frames[cam].shape[0] != T:
                raise DataImportError(
                    f"{where}: camera {cam!r} has {frames[cam].shape[0]} frames, expected {T}"
                )

        extras: dict[str, np.ndarray] = {
            "lerobot.frame_index": frame_index.astype(np.int64),
            "lerobot.timestamp": timestamp.astype(np.float32),
        }
        if gidx is not None:
            extras["lerobot.index"] = gidx.astype(np.int64)
        meta: dict[str, Any] = {"fps": self.fps, "lerobot_keys": {c: self.cameras[c] for c in cams}}
        if gaze_key and gaze_key in self.features:
            gcam = gaze_camera or self.default_gaze_camera(cams)
            if gcam not in cams:
                raise DataImportError(
                    f"{self.root}: gaze camera {gcam!r} is not among the imported cameras {cams}"
                )
            uv, valid = recorded_gaze(
                column(gaze_key), f"{where}: gaze column {gaze_key!r}", gcam in rotate180
            )
            extras[f"gaze_uv.{gcam}"], extras[f"gaze_valid.{gcam}"] = uv, valid
            meta["gaze"] = {"camera": gcam, "key": gaze_key}
        elif gaze_camera is not None:
            raise DataImportError(
                f"{self.root}: --gaze-camera {gaze_camera} given but the data set has no gaze column {gaze_key!r}"
            )
        skip = {*_STANDARD, state_key, action_key, gaze_key, *self.cameras.values()}
        for key, ft in self.features.items():
            if key in skip or ft.get("dtype") in ("video", "image", "string") or key not in sub.column_names:
                continue
            try:
                arr = column(key)
            except DataImportError:
                continue
            if arr is not None and arr.dtype.kind in "biuf" and arr.shape[0] == T:
                extras[key] = arr

        rot = [c for c in rotate180 if c in frames]
        for c in rot:
            frames[c] = np.ascontiguousarray(frames[c][:, ::-1, ::-1])
        if rot:
            meta["orientation_applied"] = dict.fromkeys(rot, "rot180")
        task_idx = column("task_index", required=False)
        tasks = list(ep.tasks)
        if task_idx is not None:
            tasks += [
                self.tasks[int(t)]
                for t in np.unique(task_idx)
                if int(t) in self.tasks and self.tasks[int(t)] not in tasks
            ]
        task = tasks[0] if tasks else ""
        meta["tasks"] = tasks
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

    def default_gaze_camera(self, cams: list[str]) -> str:
        for key in self.video_keys:
            if camera_name(key) in cams:
                return camera_name(key)
        if not cams:
            raise DataImportError(f"{self.root}: no camera to attach the gaze to")
        return cams[0]

    def _read_video(
        self, ep: _EpisodeMeta, key: str, timestamp: np.ndarray, shape: tuple[int, int] | None
    ) -> np.ndarray:
        cam = camera_name(key)
        pre = f"videos/{key}/"
        try:
            chunk, fidx, from_ts = (
                int(ep.row[pre + "chunk_index"]),
                int(ep.row[pre + "file_index"]),
                float(ep.row[pre + "from_timestamp"]),
            )
        except (KeyError, TypeError) as e:
            raise DataImportError(
                f"episode {ep.index}: camera {cam!r} ({key}) has no video segment in the episode metadata ({pre}chunk_index/file_index/from_timestamp)"
            ) from e
        path = self.root / self.info.get(
            "video_path", "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
        ).format(video_key=key, chunk_index=chunk, file_index=fidx)
        vf = self._video(key, path, ep.index)
        to_ts = ep.row.get(pre + "to_timestamp")
        times = from_ts + timestamp.astype(np.float64)
        if to_ts is not None and times[-1] >= float(to_ts) + vf.tolerance_s:
            raise DataImportError(
                f"{path}, episode {ep.index}: frame times run to {times[-1]:.4f} s, past the segment end to_timestamp={to_ts}"
            )
        try:
            return vf.read(times, shape)
        except DecodeError as e:
            raise DataImportError(f"episode {ep.index}, camera {cam!r}: {e}") from e

    def _read_images(self, sub: Any, key: str, where: str, shape: tuple[int, int] | None) -> np.ndarray:
        cam = camera_name(key)
        if key not in sub.column_names:
            raise DataImportError(f"{where}: camera {cam!r} ({key}) is missing from the data file")
        col = sub.column(key).combine_chunks()
        if hasattr(col, "field"):  # struct<bytes, path>
            data = col.field("bytes").to_pylist()
            paths = (
                col.field("path").to_pylist() if col.type.get_field_index("path") >= 0 else [None] * len(data)
            )
        else:
            data, paths = col.to_pylist(), [None] * len(col)
        out = []
        for i, (b, p) in enumerate(zip(data, paths)):
            if b is None and p:
                f = Path(p) if Path(p).is_absolute() else self.root / p
                if not f.exists():
                    raise DataImportError(f"{where}: camera {cam!r} frame {i}: image file {f} does not exist")
                b = f.read_bytes()
            if b is None:
                raise DataImportError(f"{where}: camera {cam!r} frame {i} has no image bytes")
            try:
                img = decode_image(b, f"{where}: camera {cam!r} frame {i}")
            except DecodeError as e:
                raise DataImportError(str(e)) from e
            if shape is not None and img.shape[:2] != shape:
                raise DataImportError(
                    f"{where}: camera {cam!r} frame {i} is {img.shape[0]}x{img.shape[1]}, expected {shape[0]}x{shape[1]}"
                )
            out.append(img)
        return np.stack(out)


def _image_hw(ft: dict[str, Any]) -> tuple[int, int] | None:
    """(H, W) of an image feature from its shape and names ((H, W, C) by default, or (C, H, W))."""
    shape, names = list(ft.get("shape") or []), list(ft.get("names") or [])
    if len(shape) != 3:
        return None
    if names[:1] == ["channels"] or (not names and shape[0] == 3 and shape[-1] != 3):
        return int(shape[1]), int(shape[2])
    return int(shape[0]), int(shape[1])


def _to_numpy(col: Any, what: str) -> np.ndarray:
    """A parquet column of scalars or (fixed-size) lists of numbers as an (N,) or (N, d) array."""
    pa, _ = require_pyarrow()
    col = col.combine_chunks() if hasattr(col, "combine_chunks") else col
    t = col.type
    try:
        if pa.types.is_fixed_size_list(t):
            if col.null_count:
                raise DataImportError(f"{what} has null rows")
            return np.asarray(col.flatten().to_numpy(zero_copy_only=False)).reshape(len(col), t.list_size)
        if pa.types.is_list(t) or pa.types.is_large_list(t):
            rows = col.to_pylist()
            if any(r is None for r in rows) or len({len(r) for r in rows}) > 1:
                raise DataImportError(f"{what}: rows are null or of different lengths")
            return np.asarray(rows, dtype=np.float64 if pa.types.is_floating(t.value_type) else None)
        if pa.types.is_integer(t) or pa.types.is_floating(t) or pa.types.is_boolean(t):
            return col.to_numpy(zero_copy_only=False)
    except (pa.ArrowInvalid, ValueError) as e:
        if isinstance(e, DataImportError):
            raise
        raise DataImportError(f"{what} could not be converted: {e}") from e
    raise DataImportError(f"{what} has unsupported type {t}")


# ----- import ------------------------------------------------------------------------------------------
def plan_lerobot(cfg: LeRobotImportConfig, dataset: LeRobotV3Dataset) -> list[SourceEpisode]:
    cams = list(cfg.cameras) or list(dataset.cameras)
    missing = [c for c in cams if c not in dataset.cameras]
    if missing:
        raise DataImportError(f"{dataset.root}: no camera(s) {missing}; it has {sorted(dataset.cameras)}")
    rotate = rotated_cameras(cfg.rotate180, cams, where=f" from {dataset.root}")
    has_gaze = bool(cfg.gaze_key) and cfg.gaze_key in dataset.features
    gaze_cam = (cfg.gaze_camera or dataset.default_gaze_camera(cams)) if has_gaze else None
    if has_gaze and gaze_cam not in cams:
        raise DataImportError(
            f"{dataset.root}: gaze camera {gaze_cam!r} is not among the imported cameras {cams}"
        )
    if cfg.gaze_camera is not None and not has_gaze:
        raise DataImportError(
            f"{dataset.root}: --gaze-camera {cfg.gaze_camera} given but the data set has no gaze column {cfg.gaze_key!r}"
        )
    wanted = list(cfg.episodes) or list(dataset.episodes)
    absent = [e for e in wanted if e not in dataset.episodes]
    if absent:
        raise DataImportError(f"{dataset.root}: no episode(s) {absent[:10]} (it has {len(dataset.episodes)})")
    settings = {
        "cameras": cams,
        "gaze_camera": gaze_cam,
        "gaze_key": cfg.gaze_key if has_gaze else None,
        "state_key": cfg.state_key,
        "action_key": cfg.action_key,
        "rotate180": rotate,
    }
    fp = dataset.fingerprint()
    items = []
    for e in wanted:
        identity = {
            "format": "lerobot_v3",
            "root": str(dataset.root.resolve()),
            "dataset": fp,
            "episode_index": e,
            "episode": e,
            "length": dataset.episodes[e].length,
            "settings": settings,
        }

        def load(e: int = e) -> Episode:
            return dataset.read_episode(
                e,
                cams,
                cfg.gaze_key if has_gaze else None,
                gaze_cam,
                cfg.state_key,
                cfg.action_key,
                tuple(rotate),
            )

        items.append(SourceEpisode(index=e, identity=identity, load=load, length=dataset.episodes[e].length))
    return items


def import_lerobot(cfg: LeRobotImportConfig) -> dict[str, Any]:
    """Import (or resume importing) a LeRobot v3.0 data set into cfg.out; returns counts and throughput."""
    dataset = LeRobotV3Dataset(cfg.root, tolerance_s=cfg.tolerance_s)
    items = plan_lerobot(cfg, dataset)
    store = EpisodeStore(cfg.out, create=True)
    try:
        report = write_episodes(
            store, items, total=len(items), desc=f"import {dataset.root.name}", progress=cfg.progress
        )
    finally:
        dataset.close()
    return report


def import_main(argv: list[str]) -> int:
    from gazevla.config import parse

    cfg = parse(
        {"default": LeRobotImportConfig},
        argv,
        prog="gazevla import lerobot",
        description=__doc__.split("\n\n")[0],
    )
    report = import_lerobot(cfg)
    print(json.dumps({"store": str(cfg.out), **report}))
    return 0


__all__ = [
    "SIDECAR_FORMAT",
    "SIDECAR_VERSION",
    "ExportPriorsConfig",
    "LeRobotImportConfig",
    "LeRobotPriors",
    "LeRobotV3Dataset",
    "camera_name",
    "export_main",
    "export_priors_lerobot",
    "import_lerobot",
    "import_main",
    "plan_lerobot",
    "read_priors_lerobot",
]
