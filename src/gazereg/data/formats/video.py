"""Frame decoding with PyAV (no torchvision, no lerobot): video segments by timestamp and still images.

`VideoFile` decodes the frames of one video file (AV1, H.264, anything the local FFmpeg decodes) at the
requested timestamps. LeRobot v3 packs several episodes into one MP4 and records each episode's
`from_timestamp`; a frame of that episode shown at `timestamp` (the data column) is the one whose
presentation time is `from_timestamp + timestamp`. The reader keeps its decoder open between calls, so
consecutive episodes of one file are decoded in a single forward pass; a request that jumps backwards or far
ahead seeks to the nearest key frame first.

`decode_image` decodes one PNG or JPEG image held as bytes (LeRobot "image" features).

Every failure is raised as `DecodeError` naming the file and what went wrong. An MP4 / MOV file cut short
(a copy or download that stopped) is recognised when it is opened, from its top-level boxes
(`iso_truncation`), and a seek or decode failure says that the file may be truncated or corrupt.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

# A forward gap (seconds) up to which decoding continues instead of seeking.
_SEEK_GAP_S = 2.0
_HINT = "the file may be truncated or corrupt"


class DecodeError(ValueError):
    """A video or image could not be decoded (or did not contain the requested frames)."""


def _av() -> Any:
    try:
        import av
    except ImportError as e:  # pragma: no cover - the `data` extra declares it
        raise ImportError(
            "decoding videos needs PyAV: pip install 'gazereg[data]' (or pip install av)"
        ) from e
    return av


def iso_truncation(path: Path) -> str | None:
    """Why an ISO base media file (MP4, MOV: it starts with an `ftyp` box) is cut short, or None when its
    top-level boxes fit the file (or it is not such a file, or what follows them is not a box header). Each
    box starts with its 32-bit size and type (size 1: a 64-bit size follows; size 0: the box runs to the end
    of the file); a file is reported only when a box's size runs past its end."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        if f.read(8)[4:8] != b"ftyp":
            return None
        offset = 0
        while offset + 8 <= size:
            f.seek(offset)
            head = f.read(16)
            box = int.from_bytes(head[:4], "big")
            if box == 1 and len(head) == 16:
                box = int.from_bytes(head[8:16], "big")
            if box < 8:  # 0: runs to the end; 1 without its 64-bit size, or less than a header: not a box
                return None
            if offset + box > size:
                kind = head[4:8].decode("latin-1")
                return f"its {kind!r} box at byte {offset} needs {box} bytes but the file ends after {size - offset}"
            offset += box
    return None


class VideoFile:
    """Decode frames of one video file by presentation time. Use as a context manager or call close().

    tolerance_s: a requested timestamp matches a decoded frame whose time differs by at most this much
    (plus one tick of the stream's time base, so millisecond time bases work at any frame rate).
    """

    def __init__(self, path: str | Path, tolerance_s: float = 1e-4, threads: int = 0):
        av = _av()
        self.path = Path(path)
        if not self.path.exists():
            raise DecodeError(f"video file {self.path} does not exist")
        cut = iso_truncation(self.path)
        if cut is not None:
            raise DecodeError(f"video file {self.path} is truncated: {cut} (copy it again)")
        try:
            self._container = av.open(str(self.path))
        except Exception as e:  # av.error.* (InvalidDataError, ...) and OSError
            raise DecodeError(f"video file {self.path} could not be opened ({_HINT}): {e}") from e
        if not self._container.streams.video:
            self._container.close()
            raise DecodeError(f"video file {self.path} has no video stream")
        self._stream = self._container.streams.video[0]
        if threads != 1:
            self._stream.thread_type = "AUTO"
            if threads > 1:
                self._stream.thread_count = threads
        self.time_base = float(self._stream.time_base)
        self.tolerance_s = float(tolerance_s) + self.time_base
        self.codec = self._stream.codec_context.name
        self._frames: Any = None  # the decode iterator, positioned after `_pending`
        self._pending: Any = None  # a decoded frame not yet consumed (the first one past the last request)
        self._last_time: float | None = None

    # ----- context manager ------------------------------------------------------------------------------
    def __enter__(self) -> VideoFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._container is not None:
            self._container.close()
            self._container = None

    # ----- decoding -------------------------------------------------------------------------------------
    def _seek(self, t: float) -> None:
        offset = max(int(np.floor((t - self.tolerance_s) / self.time_base)), 0)
        try:
            self._container.seek(offset, stream=self._stream, backward=True, any_frame=False)
        except Exception as e:
            raise DecodeError(f"video file {self.path}: seeking to {t:.4f} s failed ({_HINT}): {e}") from e
        self._frames = self._container.decode(self._stream)
        self._pending = None
        self._last_time = None

    def _next(self) -> Any:
        if self._pending is not None:
            frame, self._pending = self._pending, None
            return frame
        try:
            return next(self._frames)
        except StopIteration:
            return None

    def _match(self, times: np.ndarray) -> list[np.ndarray | None]:
        """Decode forward from the current position, keeping the frame within tolerance of each requested
        time (None where none is); the first frame past the last request stays pending for the next call."""
        t0, t1, tol = float(times[0]), float(times[-1]), self.tolerance_s
        out: list[np.ndarray | None] = [None] * times.size
        j = 0  # first unmatched requested time
        try:
            while j < times.size:
                frame = self._next()
                if frame is None:
                    break
                if frame.time is None:
                    raise DecodeError(f"video file {self.path}: a frame has no presentation time")
                ft = self._last_time = float(frame.time)
                if ft > t1 + tol:
                    self._pending = frame
                    break
                # skip requests this frame (and every later one) is already past
                while j < times.size and ft > times[j] + tol:
                    j += 1
                if j < times.size and abs(ft - times[j]) <= tol:
                    arr = frame.to_ndarray(format="rgb24")
                    while j < times.size and abs(ft - times[j]) <= tol:
                        out[j] = arr
                        j += 1
        except DecodeError:
            raise
        except Exception as e:  # av.error.InvalidDataError and friends
            self._frames = None
            raise DecodeError(
                f"video file {self.path}: decoding failed near {t0:.4f}-{t1:.4f} s ({_HINT}): {e}"
            ) from e
        return out

    def read(self, times: np.ndarray, shape: tuple[int, int] | None = None) -> np.ndarray:
        """Frames at the given presentation times (seconds, ascending): uint8 (N, H, W, 3) RGB.

        shape: the expected (H, W); a decoded frame of another size raises DecodeError.
        """
        times = np.asarray(times, dtype=np.float64).reshape(-1)
        if times.size == 0:
            raise DecodeError(f"video file {self.path}: no timestamps requested")
        if np.any(np.diff(times) <= 0):
            raise DecodeError(f"video file {self.path}: requested timestamps are not strictly increasing")
        if self._container is None:
            raise DecodeError(f"video file {self.path} is closed")
        t0, tol = float(times[0]), self.tolerance_s
        head = self._pending.time if self._pending is not None else self._last_time
        if self._frames is None or head is None or head > t0 + tol or t0 - head > _SEEK_GAP_S:
            self._seek(t0)
        out = self._match(times)
        missing = [i for i, f in enumerate(out) if f is None]
        if missing:
            self._frames = None  # force a fresh seek next time
            i = missing[0]
            raise DecodeError(
                f"video file {self.path}: no frame within {tol * 1e3:.3g} ms of {times[i]:.4f} s "
                f"({len(missing)} of {times.size} requested frames missing; the file is truncated, or its "
                f"timestamps do not match the metadata)"
            )
        frames = np.stack(out)  # type: ignore[arg-type]
        if shape is not None and tuple(frames.shape[1:3]) != tuple(shape):
            raise DecodeError(
                f"video file {self.path}: frames are {frames.shape[1]}x{frames.shape[2]}, expected {shape[0]}x{shape[1]}"
            )
        return frames


_MAGIC = {b"\x89PNG": "png", b"\xff\xd8\xff": "mjpeg"}
_decoders: dict[str, Any] = {}


def decode_image(data: bytes, what: str = "image") -> np.ndarray:
    """Decode PNG or JPEG bytes to uint8 (H, W, 3) RGB. `what` names the image in errors."""
    if not data:
        raise DecodeError(f"{what}: empty image bytes")
    codec = next((c for magic, c in _MAGIC.items() if data.startswith(magic)), None)
    if codec is None:
        raise DecodeError(f"{what}: not a PNG or JPEG image (starts with {data[:8]!r})")
    av = _av()
    ctx = _decoders.get(codec)
    if ctx is None:
        ctx = _decoders[codec] = av.CodecContext.create(codec, "r")
    packet = av.Packet(data)
    packet.is_keyframe = True  # PNG decoders otherwise treat the packet as a delta of the previous image
    try:
        frames = ctx.decode(packet)
    except Exception as e:
        _decoders.pop(codec, None)
        raise DecodeError(f"{what}: {codec} image could not be decoded: {e}") from e
    if not frames:
        _decoders.pop(codec, None)
        raise DecodeError(f"{what}: {codec} image decoded to nothing (truncated?)")
    return frames[0].to_ndarray(format="rgb24")
