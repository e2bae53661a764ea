"""GLC clips and gaze targets from an episode store.

Clip geometry (shared by training, the `glc` gaze source and evaluation):

* `clip_indices(T, anchors, num_frames, stride)`: the clip for anchor frame `t` holds frames
  `t + (k - num_frames // 2) * stride` for `k = 0 .. num_frames - 1` (offsets -4..3 times the stride for 8
  frames), so `t` sits at position `num_frames // 2` and its map sees past and future frames. Indices
  outside the episode are clamped to its first / last frame (edge padding by repetition).
* `average_anchors(T, num_frames, stride, hop)`: the anchors of the efficient mode: per stride phase
  `r` (frames `r, r + stride, ...`), every `hop`-th frame of that phase, plus the last frame of the phase
  when the grid would leave its end uncovered. Every frame then lies (unpadded) in `~num_frames / hop`
  computed clips.
* `preprocess_frames`: GLC's test transform: resize the short side to the crop size, centre-crop a square
  (`crop_box` says where it lies in the frame), scale to [0, 1] (normalisation with mean 0.45 / std 0.225
  is `gazereg.gaze.glc.model.prepare_clip`'s job or `normalize`).

Gaze points for training come from the episode (`episode_gaze_points`): recorded `gaze_uv.<camera>`
extras, or any registered gaze source (its `points()` if it has one, otherwise the peak of its maps).
`StoreClipDataset` serves `(clip uint8 (3, T, S, S), gaze (T, 2) in crop coordinates, valid (T,))`, the
items `gazereg.training.glc.train_glc` expects (held-out episodes: `gazereg.gaze.glc.evaluate.holdout_split`).
`write_synthetic_gaze_store` builds a toy store (moving coloured squares, gaze on the target square).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import Dataset

from gazereg.data.store import Episode, EpisodeStore
from gazereg.gaze.sources import GazeSource, make_gaze_source
from gazereg.gaze.sources.recorded import RecordedParams

# ---- clip geometry -----------------------------------------------------------------------------------


def clip_offsets(num_frames: int = 8, stride: int = 1) -> np.ndarray:
    """Frame offsets of a clip relative to its anchor: `(arange(num_frames) - num_frames // 2) * stride`."""
    if num_frames < 1 or stride < 1:
        raise ValueError(f"num_frames and stride must be >= 1, got {num_frames}, {stride}")
    return (np.arange(num_frames) - num_frames // 2) * stride


def clip_indices(
    length: int, anchors: Sequence[int] | np.ndarray, num_frames: int = 8, stride: int = 1, clamp: bool = True
) -> np.ndarray:
    """Frame indices `(len(anchors), num_frames)` of the clips centred on `anchors`.

    Position `num_frames // 2` of each row is its anchor. With `clamp` (default) indices are clamped into
    `[0, length - 1]` (edge frames repeated); without it the raw indices are returned (negative or
    `>= length` where the clip runs over an edge).
    """
    a = np.asarray(anchors, dtype=np.int64).reshape(-1, 1)
    idx = a + clip_offsets(num_frames, stride)[None, :]
    return np.clip(idx, 0, length - 1) if clamp else idx


def average_anchors(length: int, num_frames: int = 8, stride: int = 1, hop: int = 4) -> np.ndarray:
    """Anchor frames of the efficient `average` mode (sorted).

    For each stride phase `r < stride`, the phase's frames `r, r + stride, ...` get anchors at every `hop`-th
    of them, plus the phase's last frame if the last anchor's clip does not reach it. With `hop <= num_frames
    // 2` every frame lies inside at least one clip at an unpadded position; with `hop` dividing
    `num_frames` interior frames lie in exactly `num_frames / hop` of them.
    """
    if hop < 1:
        raise ValueError(f"hop must be >= 1, got {hop}")
    after = num_frames - 1 - num_frames // 2  # positions after the anchor
    out: list[int] = []
    for r in range(min(stride, length)):
        n = (length - 1 - r) // stride + 1  # frames in this phase
        grid = list(range(0, n, hop))
        if grid[-1] + after < n - 1:
            grid.append(n - 1)
        out.extend(r + stride * g for g in grid)
    return np.array(sorted(out), dtype=np.int64)


# ---- preprocessing -----------------------------------------------------------------------------------


def resized_size(height: int, width: int, crop_size: int) -> tuple[int, int]:
    """Frame size after resizing the short side to `crop_size` (aspect kept, rounded)."""
    if height <= width:
        return crop_size, max(crop_size, round(width * crop_size / height))
    return max(crop_size, round(height * crop_size / width)), crop_size


def crop_box(height: int, width: int, crop_size: int) -> tuple[float, float, float, float]:
    """Where the centre crop lies in the frame, normalised: `(u0, v0, u1, v1)` (all of it for square frames)."""
    rh, rw = resized_size(height, width, crop_size)
    top, left = (rh - crop_size) // 2, (rw - crop_size) // 2
    return (left / rw, top / rh, (left + crop_size) / rw, (top + crop_size) / rh)


def preprocess_frames(frames: np.ndarray | torch.Tensor, crop_size: int) -> torch.Tensor:
    """GLC's test transform without normalisation: uint8 `(N, H, W, 3)` frames -> float32 `(N, 3, S, S)`
    in [0, 1]: short side resized to `S = crop_size` (bilinear, antialiased when shrinking), centre crop."""
    if isinstance(frames, torch.Tensor):
        x = frames
    else:
        arr = np.asarray(frames)
        x = torch.from_numpy(
            arr if arr.flags.writeable else arr.copy()
        )  # memory-mapped episodes are read-only
    if x.ndim != 4 or x.shape[-1] != 3:
        raise ValueError(f"frames must be (N, H, W, 3), got {tuple(x.shape)}")
    x = x.permute(0, 3, 1, 2).float()
    if frames.dtype in (np.uint8, torch.uint8):
        x = x / 255.0
    h, w = x.shape[-2:]
    rh, rw = resized_size(h, w, crop_size)
    if (rh, rw) != (h, w):
        x = F.interpolate(x, size=(rh, rw), mode="bilinear", align_corners=False, antialias=True)
    top, left = (rh - crop_size) // 2, (rw - crop_size) // 2
    return x[:, :, top : top + crop_size, left : left + crop_size].contiguous()


def normalize(x: torch.Tensor, mean: float = 0.45, std: float = 0.225) -> torch.Tensor:
    return (x - mean) / std


def points_to_crop(points: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray:
    """Normalised frame coordinates `(..., 2)` -> coordinates in the crop (outside the crop: outside [0, 1])."""
    u0, v0, u1, v1 = box
    p = np.asarray(points, dtype=np.float32).copy()
    p[..., 0] = (p[..., 0] - u0) / (u1 - u0)
    p[..., 1] = (p[..., 1] - v0) / (v1 - v0)
    return p


# ---- gaze points -------------------------------------------------------------------------------------


def map_peaks(heatmaps: np.ndarray) -> np.ndarray:
    """Normalised `(u, v)` of each map's maximum cell centre: `(T, h, w)` -> `(T, 2)`."""
    T, h, w = heatmaps.shape
    flat = np.asarray(heatmaps).reshape(T, -1).argmax(1)
    i, j = np.divmod(flat, w)
    return np.stack([(j + 0.5) / w, (i + 0.5) / h], axis=1).astype(np.float32)


def _recorded_points(episode: Episode, camera: str, key: str) -> tuple[np.ndarray, np.ndarray]:
    """`extra.<key>.<camera>` `(T, 2)` and `extra.gaze_valid.<camera>` `(T,)` (all True when absent)."""
    T = episode.length
    name = f"{key}.{camera}"
    if name not in episode.extras:
        have = sorted(k for k in episode.extras if k.startswith("gaze"))
        raise KeyError(
            f"episode {episode.index} has no recorded gaze {name!r} (gaze extras: {have or 'none'})"
        )
    pts = np.asarray(episode.extras[name], dtype=np.float32).reshape(T, 2)
    valid = np.ones(T, bool)
    if f"gaze_valid.{camera}" in episode.extras:
        valid &= np.asarray(episode.extras[f"gaze_valid.{camera}"]).astype(bool).reshape(T)
    return pts, valid


def _source_points(
    episode: Episode, camera: str, source: Any, peak_size: int
) -> tuple[np.ndarray, np.ndarray]:
    """A gaze source's own points (`points()`, or `trace()` of the visuomotor source), else its maps' peaks."""
    T = episode.length
    if hasattr(source, "points"):
        pts, valid = source.points(episode, camera)
    elif hasattr(source, "trace"):  # the visuomotor source: a GazeTrace with uv (T, 2) and valid (T,)
        trace = source.trace(episode, camera)
        pts, valid = trace.uv, trace.valid
    else:
        maps, valid = source(episode, camera, (peak_size, peak_size))
        return map_peaks(np.asarray(maps)), np.asarray(valid).astype(bool)
    return np.asarray(pts, dtype=np.float32).reshape(T, 2), np.asarray(valid).astype(bool).reshape(T)


def episode_gaze_points(
    episode: Episode,
    camera: str,
    source: str | RecordedParams | GazeSource = "recorded",
    key: str = "gaze_uv",
    peak_size: int = 64,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame gaze points `(T, 2)` normalised `(u, v)` in the stored frame (NaN where not valid), and
    `valid (T,)`.

    Args:
        source: `"recorded"` reads `extra.<key>.<camera>` (NaN = lost) and `extra.gaze_valid.<camera>`, and so
            do `RecordedParams` (with their own `key`); anything else is a gaze source name or object: its
            `points(episode, camera)` or `trace(episode, camera)` (`.uv`, `.valid`; the visuomotor source) if
            it has one, otherwise the peak cell of its `peak_size` x `peak_size` maps.
    """
    if isinstance(source, RecordedParams):
        pts, valid = _recorded_points(episode, camera, source.key)
    elif isinstance(source, str) and source == "recorded":
        pts, valid = _recorded_points(episode, camera, key)
    else:
        source = make_gaze_source(source) if isinstance(source, str) else source
        pts, valid = _source_points(episode, camera, source, peak_size)
    valid = valid & np.isfinite(pts).all(1) & ((pts >= 0) & (pts <= 1)).all(1)
    pts = np.where(valid[:, None], pts, np.nan).astype(np.float32)
    return pts, valid


def fixation_mask(points: np.ndarray, valid: np.ndarray, max_move: float) -> np.ndarray:
    """Frames whose gaze moved at most `max_move` (normalised units) since the previous frame (the first valid
    frame of a run counts as a fixation); `max_move <= 0` keeps every valid frame."""
    valid = np.asarray(valid, bool)
    if max_move <= 0:
        return valid.copy()
    move = np.full(len(valid), 0.0)
    move[1:] = np.linalg.norm(np.diff(np.nan_to_num(points), axis=0), axis=1)
    move[1:][~valid[:-1]] = 0.0
    return valid & (move <= max_move)


# ---- training data -----------------------------------------------------------------------------------


@dataclass
class EpisodeClips:
    """One episode ready for clip sampling: cropped frames, gaze in crop coordinates."""

    index: int
    frames: torch.Tensor  # uint8 (T, 3, S, S)
    points: torch.Tensor  # float32 (T, 2), crop coordinates (NaN / outside [0,1] where unusable)
    valid: torch.Tensor  # bool (T,)


def load_episode_clips(
    store: EpisodeStore, index: int, camera: str, crop_size: int, source: Any = "recorded", chunk: int = 256
) -> EpisodeClips:
    ep = store.read(index, cameras=[camera])
    pts, valid = episode_gaze_points(ep, camera, source)
    fr = ep.frames[camera]
    T, H, W = fr.shape[:3]
    out = torch.empty(T, 3, crop_size, crop_size, dtype=torch.uint8)
    for s in range(0, T, chunk):
        x = preprocess_frames(np.asarray(fr[s : s + chunk]), crop_size)
        out[s : s + chunk] = (x * 255.0).round().clamp(0, 255).to(torch.uint8)
    crop_pts = points_to_crop(pts, crop_box(H, W, crop_size))
    return EpisodeClips(index, out, torch.from_numpy(crop_pts), torch.from_numpy(valid))


class StoreClipDataset(Dataset):
    """Clips of `num_frames` frames (clip geometry of `clip_indices`) anchored at every `hop`-th frame of the
    given episodes. Item: `(clip uint8 (3, T, S, S), gaze (T, 2) crop coords, valid (T,))`."""

    def __init__(
        self,
        store: EpisodeStore,
        indices: Sequence[int],
        camera: str,
        crop_size: int,
        num_frames: int = 8,
        stride: int = 1,
        hop: int = 1,
        source: Any = "recorded",
    ) -> None:
        if isinstance(source, str) and source != "recorded":
            source = make_gaze_source(source)
        if hasattr(source, "bind"):
            source.bind(store)
        self.episodes = [load_episode_clips(store, i, camera, crop_size, source) for i in indices]
        self.num_frames, self.stride = num_frames, stride
        self.items = [(k, t) for k, e in enumerate(self.episodes) for t in range(0, e.frames.shape[0], hop)]
        if not self.items:
            raise ValueError("no clips: the episode list is empty")

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, i: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        k, t = self.items[i]
        e = self.episodes[k]
        idx = torch.from_numpy(clip_indices(e.frames.shape[0], [t], self.num_frames, self.stride)[0])
        return e.frames[idx].permute(1, 0, 2, 3), e.points[idx], e.valid[idx]

    def gaze(self) -> tuple[torch.Tensor, torch.Tensor]:
        """All frames' gaze points (crop coordinates) and validity, concatenated over episodes."""
        return torch.cat([e.points for e in self.episodes]), torch.cat([e.valid for e in self.episodes])


# ---- a synthetic store -------------------------------------------------------------------------------

_COLOURS = np.array([[230, 40, 40], [40, 200, 60], [50, 90, 230], [230, 210, 40]], np.float32)


def synthetic_gaze_episode(
    length: int = 48,
    size: int = 96,
    camera: str = "cam",
    seed: int = 0,
    n_objects: int = 3,
    task: str = "synthetic",
) -> Episode:
    """Coloured squares drifting (bouncing) over a textured background; the gaze follows the red one
    (object 0, drawn on top); its start is random, so a centre prior is a poor guess.
    Gaze is stored as `extra.gaze_uv.<camera>` (recorded gaze)."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(0.15, 0.85, (n_objects, 2))
    vel = rng.uniform(-0.02, 0.02, (n_objects, 2))
    half = 0.07
    yy, xx = (np.mgrid[0:size, 0:size] + 0.5) / size
    bg = 70 + 25 * np.sin(9 * xx + rng.uniform(0, 6)) * np.cos(7 * yy + rng.uniform(0, 6))
    frames = np.empty((length, size, size, 3), np.uint8)
    gaze = np.empty((length, 2), np.float32)
    for t in range(length):
        img = np.repeat(bg[..., None], 3, axis=2) + rng.normal(0, 4, (size, size, 3))
        for k in range(n_objects - 1, -1, -1):  # object 0 drawn last (on top)
            m = (np.abs(xx - pos[k, 0]) < half) & (np.abs(yy - pos[k, 1]) < half)
            img[m] = _COLOURS[k % len(_COLOURS)]
        frames[t] = np.clip(img, 0, 255).astype(np.uint8)
        gaze[t] = pos[0]
        pos += vel
        bounce = (pos < 0.1) | (pos > 0.9)
        vel[bounce] *= -1
        pos = np.clip(pos, 0.1, 0.9)
    return Episode(
        task=task,
        instruction="follow the red square",
        frames={camera: frames},
        state=np.zeros((length, 1), np.float32),
        action=np.zeros((length, 1), np.float32),
        extras={f"gaze_uv.{camera}": gaze},
        meta={"seed": seed, "synthetic": True},
    )


def write_synthetic_gaze_store(
    root: str | Path,
    episodes: int = 10,
    length: int = 48,
    size: int = 96,
    camera: str = "cam",
    seed: int = 0,
    tasks: int = 1,
) -> EpisodeStore:
    """A store of `episodes` synthetic episodes (tasks `synthetic-0..`, assigned round-robin)."""
    store = EpisodeStore(root, create=True)
    for i in range(episodes):
        store.write(
            synthetic_gaze_episode(
                length, size, camera, seed=seed * 100_003 + i, task=f"synthetic-{i % tasks}"
            )
        )
    return store


def n_clips(length: int, mode: str, stride: int, hop: int, num_frames: int = 8) -> int:
    """How many clips the `glc` source computes for an episode of `length` frames."""
    if mode == "centre":
        return length
    return len(average_anchors(length, num_frames, stride, hop))


__all__ = [
    "EpisodeClips",
    "StoreClipDataset",
    "average_anchors",
    "clip_indices",
    "clip_offsets",
    "crop_box",
    "episode_gaze_points",
    "fixation_mask",
    "load_episode_clips",
    "map_peaks",
    "n_clips",
    "normalize",
    "points_to_crop",
    "preprocess_frames",
    "synthetic_gaze_episode",
    "write_synthetic_gaze_store",
]
