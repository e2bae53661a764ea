"""The `glc` gaze source: per-frame gaze maps predicted by the GLC video gaze estimator.

    gazereg priors --store S --source glc --source-params checkpoint=runs/glc/final stride=2
    make_gaze_source(GLCParams(checkpoint=Path("GLC_ego4d.pyth"), config="official", mode="centre"))

For frame t the 8-frame clip is centred on t: frames `t + (k - 4) * stride`, k = 0..7 (t at position 4),
edge frames repeated (`gazereg.gaze.glc.data.clip_indices`). Frames are used as stored (upright, as the policy
sees them) and preprocessed as GLC's test transform: short side resized to the crop size, centre crop,
mean 0.45 / std 0.225. Maps are the per-frame softmax of `logits / temperature` (GLC: 2).

Modes:
* `centre`: one clip per frame, keep the map at the centre position (T clips per episode).
* `average` (default, the efficient mode): clips centred on every `hop`-th frame of each stride phase
  (`gazereg.gaze.glc.data.average_anchors`); frame t's map is the mean of the maps that every computed clip
  containing t predicts for it (positions that are edge padding are not used). About T / hop clips, each
  frame averaged over ~8 / hop maps; `hop=1` averages all 8 overlapping centred clips.

The maps (over the centre crop) are put back into the frame (zero outside the crop for non-square
frames), resized to the requested size (area when shrinking, bilinear when enlarging) and renormalised.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
import torch
import torch.nn.functional as F

from gazereg.data.store import Episode
from gazereg.gaze.glc.checkpoint import CONFIG_NAME, WEIGHTS_NAME, load_glc, load_glc_checkpoint
from gazereg.gaze.glc.data import average_anchors, clip_indices, normalize, preprocess_frames, resized_size
from gazereg.gaze.glc.model import GLC, GLCConfig, frame_softmax
from gazereg.gaze.sources import register_gaze_source
from gazereg.gaze.sources.params import GazeSourceParams
from gazereg.runtime.errors import UsageError

CONFIGS = {"official": GLCConfig.official, "small": GLCConfig.small}
"""the GLC sizes (`gazereg presets`): the official architecture and a small one"""
MODES = ("centre", "average")
GLCConfigName = Literal["official", "small"]
GLCMode = Literal["centre", "average"]


def config_name(cfg: GLCConfig) -> str:
    for name, make in CONFIGS.items():
        if make() == cfg:
            return name
    return "custom"


def file_sha256(path: Path, limit: int | None = None) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()[:limit] if limit else h.hexdigest()


def load_glc_model(
    checkpoint: str | Path | None, config: str | None = None, seed: int = 0
) -> tuple[GLC, dict[str, Any]]:
    """Build a GLC from `checkpoint` and return it (eval mode, CPU) with a provenance record.

    `checkpoint` is a folder written by `save_glc` / `gazereg glc train` (its `config.json` decides the
    architecture; a run folder with a `final/` subfolder is accepted too), an official GLC checkpoint
    file (architecture from `config`, default `official`), or the literal `random` (random weights seeded by
    `seed`: only for tests and benchmarks).
    """
    if checkpoint is None or str(checkpoint) == "":
        raise UsageError(
            "the glc gaze source needs a checkpoint: checkpoint=<folder written by `gazereg glc train`> or "
            "checkpoint=<official GLC .pyth file> config=official (checkpoint=random only for tests/benchmarks)"
        )
    if config is not None and config not in CONFIGS:
        raise UsageError(f"unknown GLC config {config!r}; use one of {sorted(CONFIGS)}")
    if str(checkpoint) == "random":
        torch.manual_seed(seed)
        model = GLC(CONFIGS[config or "official"]())
        return model.eval(), {"checkpoint": "random", "seed": seed}
    path = Path(checkpoint).expanduser()
    if not path.exists():
        raise FileNotFoundError(
            f"GLC checkpoint {str(path)!r} does not exist (a folder from `gazereg glc train` or an official file)"
        )
    if path.is_dir():
        if not (path / CONFIG_NAME).exists() and (path / "final" / CONFIG_NAME).exists():
            path = path / "final"
        if not (path / CONFIG_NAME).exists() or not (path / WEIGHTS_NAME).exists():
            raise FileNotFoundError(
                f"{path} is not a GLC checkpoint folder (needs {CONFIG_NAME} and {WEIGHTS_NAME})"
            )
        model = load_glc(path)
        if config is not None and model.cfg != CONFIGS[config]():
            raise UsageError(f"checkpoint {path} holds a {config_name(model.cfg)!r} GLC, not {config!r}")
        weights = path / WEIGHTS_NAME
    else:
        model = load_glc_checkpoint(GLC(CONFIGS[config or "official"]()), path)
        weights = path
    return model.eval(), {"checkpoint": str(path.resolve()), "checkpoint_sha256": file_sha256(weights, 16)}


@dataclass(frozen=True)
class GLCParams(GazeSourceParams):
    """Parameters of the `glc` source.

    checkpoint: folder from `gazereg glc train` / `save_glc`, an official checkpoint file, or `random`.
    config: `official` | `small` for official files and `random` (folders carry their own config).
    stride: frames between the clip's frames (the clip spans `8 * stride` frames).
    mode: `average` (default) or `centre`.
    hop: in `average` mode, clip spacing in frames of one stride phase.
    batch_size: clips per forward pass.
    device: torch device to run on (explicit; default cpu).
    temperature: softmax temperature (default: the model's, 2).
    seed: the seed of `checkpoint=random`.
    """

    name: ClassVar[str] = "glc"
    checkpoint: Path | None = None
    config: GLCConfigName | None = None
    stride: int = 2
    mode: GLCMode = "average"
    hop: int = 4
    batch_size: int = 8
    device: str = "cpu"
    temperature: float | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise UsageError(f"mode must be one of {MODES}, got {self.mode!r}")
        if self.config is not None and self.config not in CONFIGS:
            raise UsageError(f"unknown GLC config {self.config!r}; use one of {sorted(CONFIGS)}")
        if self.stride < 1 or self.hop < 1 or self.batch_size < 1:
            raise UsageError(
                f"stride, hop and batch_size must be >= 1, got {self.stride}, {self.hop}, {self.batch_size}"
            )


@register_gaze_source(GLCParams)
class GLCGaze:
    """Gaze maps from a GLC checkpoint (see the module docstring and `GLCParams`)."""

    name = "glc"

    def __init__(self, params: GLCParams = GLCParams()):
        self.model, self._provenance = load_glc_model(params.checkpoint, params.config, params.seed)
        self.cfg = self.model.cfg
        self.device = torch.device(params.device)
        self.model.to(self.device)
        self.stride, self.mode, self.hop = int(params.stride), params.mode, int(params.hop)
        self.batch_size = int(params.batch_size)
        self.temperature = float(self.cfg.temperature if params.temperature is None else params.temperature)

    def describe(self) -> dict[str, Any]:
        """Everything that determines the maps (batch size and device do not, so a run can resume elsewhere)."""
        d = {
            "name": self.name,
            **self._provenance,
            "config": config_name(self.cfg),
            "glc_config": self.cfg.to_dict(),
            "params": self.model.num_parameters(),
            "stride": self.stride,
            "mode": self.mode,
            "hop": self.hop if self.mode == "average" else None,
            "temperature": self.temperature,
            "preprocess": "short side to crop size, centre crop, mean 0.45 std 0.225; frames as stored",
        }
        return json.loads(json.dumps(d))  # tuples -> lists, so a stored record compares equal on resume

    # ---- clips ---------------------------------------------------------------------------------------
    def plan(self, length: int) -> tuple[np.ndarray, np.ndarray]:
        """`(clips (N, num_frames) clamped frame indices, targets (N, num_frames))`: the frame each position's map
        is kept for, or -1 where it is not used."""
        nf = self.cfg.num_frames
        if self.mode == "centre":
            anchors = np.arange(length)
            clips = clip_indices(length, anchors, nf, self.stride)
            targets = np.full_like(clips, -1)
            targets[:, nf // 2] = anchors
            return clips, targets
        anchors = average_anchors(length, nf, self.stride, self.hop)
        raw = clip_indices(length, anchors, nf, self.stride, clamp=False)
        targets = np.where((raw >= 0) & (raw < length), raw, -1)
        return np.clip(raw, 0, length - 1), targets

    @torch.inference_mode()
    def predict(self, frames: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-frame maps over the centre crop at the model's output size: `(T, h, w)` float32 (each summing
        to 1) and the number of maps averaged per frame `(T,)`."""
        T = int(frames.shape[0])
        clips, targets = self.plan(T)
        _, h, w = self.cfg.output_shape
        acc = torch.zeros(T, h * w, dtype=torch.float32)
        count = torch.zeros(T, dtype=torch.float32)
        S = self.cfg.crop_size
        for s in range(0, len(clips), self.batch_size):
            idx = clips[s : s + self.batch_size]
            tgt = torch.from_numpy(targets[s : s + self.batch_size])
            uniq, inv = np.unique(idx, return_inverse=True)
            pre = preprocess_frames(np.asarray(frames[uniq]), S)  # only the frames this batch needs
            x = normalize(pre, self.cfg.mean, self.cfg.std).to(self.device)
            x = x[torch.from_numpy(inv.reshape(idx.shape)).to(self.device)]  # (B, nf, 3, S, S)
            x = x.permute(0, 2, 1, 3, 4).contiguous()
            maps = frame_softmax(self.model(x), self.temperature).float().cpu()  # (B, nf, h, w)
            keep = tgt >= 0
            acc.index_add_(0, tgt[keep], maps[keep].reshape(-1, h * w))
            count.index_add_(0, tgt[keep], torch.ones(int(keep.sum())))
        if (count == 0).any():  # cannot happen by construction of plan(); guard anyway
            raise RuntimeError(f"frames {torch.nonzero(count == 0).flatten().tolist()} got no map")
        return (acc / count[:, None]).reshape(T, h, w), count

    def __call__(self, episode: Episode, camera: str, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        if camera not in episode.frames:
            raise UsageError(
                f"episode {episode.index} has no camera {camera!r}; it has {sorted(episode.frames)}"
            )
        frames = episode.frames[camera]
        maps, _ = self.predict(frames)
        H, W = frames.shape[1:3]
        out = to_frame(maps, (H, W), self.cfg.crop_size, tuple(size))
        total = out.flatten(1).sum(1)
        valid = torch.isfinite(total) & (total > 0)
        out = torch.where(
            valid[:, None, None], out / total.clamp_min(1e-30)[:, None, None], torch.zeros_like(out)
        )
        return out.numpy().astype(np.float32), valid.numpy()


def resize_maps(maps: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Resize `(T, h, w)` maps: area when shrinking (both sides), bilinear otherwise; clamped at 0."""
    h, w = maps.shape[-2:]
    if (h, w) == tuple(size):
        return maps
    mode = "area" if size[0] <= h and size[1] <= w else "bilinear"
    kw = {} if mode == "area" else {"align_corners": False}
    return F.interpolate(maps[:, None], size=size, mode=mode, **kw)[:, 0].clamp_min(0)


def to_frame(
    maps: torch.Tensor, frame_hw: tuple[int, int], crop_size: int, size: tuple[int, int]
) -> torch.Tensor:
    """Maps over the centre crop -> maps over the whole frame on a `size` grid (not renormalised).

    Square frames: the crop is the frame, so this is a resize. Otherwise the maps are resized to the crop's
    pixels in the resized frame, pasted there on a zero canvas, and the canvas resized to `size`."""
    H, W = frame_hw
    rh, rw = resized_size(H, W, crop_size)
    if (rh, rw) == (crop_size, crop_size):
        return resize_maps(maps, size)
    top, left = (rh - crop_size) // 2, (rw - crop_size) // 2
    canvas = maps.new_zeros(maps.shape[0], rh, rw)
    canvas[:, top : top + crop_size, left : left + crop_size] = resize_maps(maps, (crop_size, crop_size))
    return resize_maps(canvas, size)
