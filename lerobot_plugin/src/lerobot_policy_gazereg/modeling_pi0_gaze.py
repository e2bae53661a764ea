"""pi0 with gaze regularization: PI0Policy unchanged (same modules, same state dict, same inference), plus, in
training, weight * KL(gaze || attention of the action expert's action tokens to one camera's image tokens).

The loss dict gains `loss/action` (pi0's own loss), `loss/gaze_kl` (the unweighted divergence), `gaze/weight`,
`gaze/valid_frac` and `gaze/patch_mass`; lerobot-train logs every scalar of it. `gaze_target_mass=m` selects
the mass variant of the term, as for `smolvla_gaze`. The gaze column comes from the
batch or, when the pre-processor dropped it, from the data set's parquet files (as for `smolvla_gaze`).

Image geometry (lerobot 0.6.1 `_preprocess_images`): a frame that is not `image_resolution` goes through
`resize_with_pad_torch` (keep the aspect ratio, centred padding), then SigLIP patches (`patch_size` px, no pixel
shuffle): one image token per patch, row-major.
"""

from __future__ import annotations

import logging
from types import ModuleType
from typing import Any, ClassVar

from lerobot.policies.pi0 import modeling_pi0
from lerobot.policies.pi0.modeling_pi0 import PI0Policy
from torch import Tensor

from gazereg.patches import PatchGeometry

from .build_checks import check_before_build, gaze_frame_shape
from .capture_pi0 import PiCapture, depth_text
from .configuration_pi0_gaze import PI0GazeConfig
from .errors import refusing
from .gaze_common import GazeActivity, finish_gaze_forward, gaze_camera_index
from .gaze_targets import gaze_valid_flag
from .modeling_smolvla_gaze import SmolVLAGazePolicy

log = logging.getLogger(__name__)


def pi_geometry(src_hw: tuple[int, int], input_hw: tuple[int, int], patch_size: int) -> PatchGeometry:
    """The PatchGeometry of pi0/pi05 for a stored (height, width) frame and `image_resolution` (height, width)."""
    H, W = src_hw
    h_in, w_in = input_hw
    if H * w_in == W * h_in:  # same aspect (or same size): a plain resize, no padding
        return PatchGeometry(input_hw=(h_in, w_in), patch_size=patch_size)
    return PatchGeometry(
        input_hw=(h_in, w_in), patch_size=patch_size, src_hw=(H, W), resize="fit", pad="centre"
    )


def pi_camera_geometry(cfg: Any, patch_size: int) -> tuple[PatchGeometry, tuple[int, int]]:
    """(token geometry, stored (height, width)) of the regularized camera's frames for SigLIP patches of
    `patch_size` px (pi_geometry at the config's `image_resolution`)."""
    shape = cfg.image_features[cfg.gaze_camera_key()].shape  # (C, H, W)
    src_hw = (int(shape[-2]), int(shape[-1]))
    h_in, w_in = (int(x) for x in cfg.image_resolution)
    return pi_geometry(src_hw, (h_in, w_in), patch_size), src_hw


class PiGazeMixin:
    """The gaze term of `pi0_gaze` / `pi05_gaze`, mixed in before PI0Policy / PI05Policy."""

    # lerobot's modeling module of the base policy: its gemma variants and PaliGemma config build the model
    _lerobot_modeling: ClassVar[ModuleType] = modeling_pi0

    # the gaze column lookup (batch, else the data set's parquet by `index`) is smolvla_gaze's
    _gaze_column = SmolVLAGazePolicy._gaze_column

    @classmethod
    def lerobot_model_shape(cls, config: Any) -> tuple[int, int]:
        """(layer count, SigLIP patch size in px) of the model lerobot builds for `config`, read without building
        it: `get_gemma_config(paligemma_variant).depth` and its PaliGemma config's vision patch size."""
        mod = cls._lerobot_modeling
        depth = int(mod.get_gemma_config(config.paligemma_variant).depth)
        return depth, int(mod.CONFIG_MAPPING["paligemma"]().vision_config.patch_size)

    @classmethod
    def _check_before_build(cls, config: Any, meta: Any) -> None:
        """build_checks.check_before_build against `lerobot_model_shape`."""
        depth, patch = cls.lerobot_model_shape(config)
        layers = (range(depth), depth_text(depth))
        check_before_build(config, meta, layers, lambda: pi_camera_geometry(config, patch)[0])

    def _init_gaze(self, kwargs: dict[str, Any]) -> None:
        self.gaze_capture = PiCapture(self.model, self.config.gaze_layers)
        meta = kwargs.get("dataset_meta")
        self._gaze_root = getattr(meta, "root", None)
        self._gaze_table: tuple[Tensor, Tensor] | None = None
        self._gaze_geometry: tuple[PatchGeometry, tuple[int, int]] | None = None
        self._gaze_frame = gaze_frame_shape(self.config, meta)
        self._gaze_activity = GazeActivity(self.config.gaze_key)

    def _geometry(self) -> tuple[PatchGeometry, tuple[int, int]]:
        if self._gaze_geometry is None:
            patch = self.model.paligemma_with_expert.paligemma.config.vision_config.patch_size
            self._gaze_geometry = pi_camera_geometry(self.config, patch)
        return self._gaze_geometry

    def forward(self, batch: dict[str, Tensor], reduction: str = "mean") -> tuple[Tensor, dict[str, Any]]:
        cfg = self.config
        if not self.training or cfg.gaze_weight == 0:
            return super().forward(batch, reduction=reduction)
        cam, cam_index = gaze_camera_index(cfg, batch)
        column = self._gaze_column(batch)
        with refusing():
            flag = gaze_valid_flag(batch, cfg.gaze_key)
        with self.gaze_capture.capture(cam_index, cfg.chunk_size):
            loss, loss_dict = super().forward(batch, reduction=reduction)
        geom, src_hw = self._geometry()
        return finish_gaze_forward(
            self, cam, cam_index, column, flag, (geom, False, src_hw), loss, loss_dict, reduction
        )


class PI0GazePolicy(PiGazeMixin, PI0Policy):
    config_class = PI0GazeConfig
    name = "pi0_gaze"

    def __init__(self, config: PI0GazeConfig, **kwargs: Any):
        self._check_before_build(config, kwargs.get("dataset_meta"))  # before PaliGemma (and its weights)
        super().__init__(config, **kwargs)
        self._init_gaze(kwargs)
