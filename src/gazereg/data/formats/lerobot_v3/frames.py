"""Camera frames of a LeRobot v3.0 episode: "video" features from the episode's segment of the camera's MP4,
"image" features from the PNG/JPEG bytes (or files) in the data parquet.

A frame shown at `timestamp` (the data column) is the video frame at `from_timestamp + timestamp`, where
`videos/<key>/from_timestamp` in the episode metadata is where the episode's segment starts; decoding itself
is gazereg.data.formats.video's.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from gazereg.data.errors import DataImportError
from gazereg.data.formats.lerobot_v3.metadata import DEFAULT_VIDEO_PATH, EpisodeMeta, camera_name
from gazereg.data.formats.video import DecodeError, VideoFile, decode_image


class VideoFrames:
    """Reads episodes' frames from a data set's videos, keeping one video file per camera open (consecutive
    episodes of one file are decoded in a single forward pass)."""

    def __init__(self, root: Path, info: dict[str, Any], tolerance_s: float = 1e-4):
        self.root = root
        self.path_template = info.get("video_path", DEFAULT_VIDEO_PATH)
        self.tolerance_s = tolerance_s
        self._open: dict[str, VideoFile] = {}

    def read(
        self, ep: EpisodeMeta, key: str, timestamp: np.ndarray, shape: tuple[int, int] | None
    ) -> np.ndarray:
        """(T, H, W, 3) uint8 frames of feature `key` at the episode's timestamps."""
        path, from_ts, to_ts = self._segment(ep, key)
        vf = self._video(key, path, ep.index)
        times = from_ts + timestamp.astype(np.float64)
        if to_ts is not None and times[-1] >= float(to_ts) + vf.tolerance_s:
            raise DataImportError(
                f"{path}, episode {ep.index}: frame times run to {times[-1]:.4f} s, past the segment end to_timestamp={to_ts}"
            )
        try:
            return vf.read(times, shape)
        except DecodeError as e:
            raise DataImportError(f"episode {ep.index}, camera {camera_name(key)!r}: {e}") from e

    def _segment(self, ep: EpisodeMeta, key: str) -> tuple[Path, float, Any]:
        """The video file of the episode's segment, its start and its end (None where not recorded)."""
        pre = f"videos/{key}/"
        try:
            chunk, fidx, from_ts = (
                int(ep.row[pre + "chunk_index"]),
                int(ep.row[pre + "file_index"]),
                float(ep.row[pre + "from_timestamp"]),
            )
        except (KeyError, TypeError) as e:
            raise DataImportError(
                f"episode {ep.index}: camera {camera_name(key)!r} ({key}) has no video segment in the episode metadata ({pre}chunk_index/file_index/from_timestamp)"
            ) from e
        path = self.root / self.path_template.format(video_key=key, chunk_index=chunk, file_index=fidx)
        return path, from_ts, ep.row.get(pre + "to_timestamp")

    def _video(self, key: str, path: Path, episode: int) -> VideoFile:
        """The open video file of camera `key`, opening `path` (and closing the camera's previous file)."""
        vf = self._open.get(key)
        if vf is not None and vf.path == path:
            return vf
        if vf is not None:
            vf.close()
            del self._open[key]
        if not path.exists():
            raise DataImportError(
                f"episode {episode}: video of camera {camera_name(key)!r} ({key}) is missing: {path} does not exist"
            )
        try:
            vf = VideoFile(path, tolerance_s=self.tolerance_s)
        except DecodeError as e:
            raise DataImportError(f"episode {episode}, camera {camera_name(key)!r}: {e}") from e
        self._open[key] = vf
        return vf

    def close(self) -> None:
        for vf in self._open.values():
            vf.close()
        self._open.clear()


def _image_cells(col: Any) -> tuple[list[bytes | None], list[str | None]]:
    """An image column's encoded bytes and file paths, row by row (struct<bytes, path> or plain bytes)."""
    col = col.combine_chunks()
    if not hasattr(col, "field"):
        return col.to_pylist(), [None] * len(col)
    data = col.field("bytes").to_pylist()
    has_path = col.type.get_field_index("path") >= 0
    return data, col.field("path").to_pylist() if has_path else [None] * len(data)


def _image_bytes(data: bytes | None, path: str | None, root: Path, what: str) -> bytes:
    """An image's bytes: held in the data file, or read from its file (relative to the data set root)."""
    if data is None and path:
        f = Path(path) if Path(path).is_absolute() else root / path
        if not f.exists():
            raise DataImportError(f"{what}: image file {f} does not exist")
        data = f.read_bytes()
    if data is None:
        raise DataImportError(f"{what} has no image bytes")
    return data


def read_images(rows: Any, key: str, root: Path, where: str, shape: tuple[int, int] | None) -> np.ndarray:
    """(T, H, W, 3) uint8 frames of image feature `key` from an episode's rows of the data file."""
    cam = camera_name(key)
    if key not in rows.column_names:
        raise DataImportError(f"{where}: camera {cam!r} ({key}) is missing from the data file")
    out = []
    for i, (data, path) in enumerate(zip(*_image_cells(rows.column(key)))):
        what = f"{where}: camera {cam!r} frame {i}"
        try:
            img = decode_image(_image_bytes(data, path, root, what), what)
        except DecodeError as e:
            raise DataImportError(str(e)) from e
        if shape is not None and img.shape[:2] != shape:
            raise DataImportError(f"{what} is {img.shape[0]}x{img.shape[1]}, expected {shape[0]}x{shape[1]}")
        out.append(img)
    return np.stack(out)
