"""SmolVLA with gaze regularization: SmolVLAPolicy unchanged (same modules, same state dict, same inference),
plus, in training, weight * KL(gaze || attention of the action expert's tokens to one camera's image tokens).

The loss dict gains `loss/action` (SmolVLA's own loss), `loss/gaze_kl` (the unweighted divergence),
`gaze/weight`, `gaze/valid_frac` and `gaze/patch_mass` (the attention mass on the camera's image tokens, in
[0, 1]: a falling KL with a collapsing mass means the term is met by looking away from the image); lerobot-train
logs every scalar of it. With `gaze_target_mass=m` (0 < m <= 1) the term is the mass variant
(gazereg.integrations.gaze_mass): KL over the image tokens plus one non-image bin with target mass m.

Where the gaze comes from, per training batch:
1. the batch's `gaze_key` column (kept through the pre-processor by this plugin's processor factory);
2. otherwise, when the pre-processor dropped it (a processor loaded from a checkpoint uses LeRobot's default
   converters, which keep only observation.*, action, *_is_pad and a few metadata keys), the same column read
   once from the data set's parquet files (the policy receives the data set metadata) and looked up by the
   batch's `index`.

Before the model is built (so before any weights load) `gaze_layers` and the data set's gaze column are checked
(gaze_common.check_gaze_features in the config's feature hook; build_checks.check_before_build here: layers the
action expert does not attend at, a column without a single usable frame, a token-distribution column whose
length is not the camera's token count are refused), and while training `GazeActivity` stops a run whose gaze term is never
active; each refusal is one line naming the column (errors.refusing).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import torch
from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy
from torch import Tensor
from transformers import AutoConfig

from gazereg.patches import PatchGeometry

from .build_checks import check_before_build, gaze_frame_shape
from .capture import SmolVLACapture, expert_layers, expert_layers_text
from .configuration_smolvla_gaze import SmolVLAGazeConfig
from .errors import refusing
from .gaze_common import GazeActivity, finish_gaze_forward, gaze_camera_index
from .gaze_targets import gaze_valid_flag, smolvla_geometry

log = logging.getLogger(__name__)


def _load_gaze_column(root: Path, key: str) -> tuple[Tensor, Tensor] | None:
    """(index (N,) long, values (N, ...) float32) of a LeRobot v3 data set's column, or None if absent."""
    import pyarrow.parquet as pq

    files = sorted((Path(root) / "data").glob("*/*.parquet"))
    idx, vals = [], []
    for f in files:
        names = pq.read_schema(f).names
        if key not in names or "index" not in names:
            return None
        t = pq.read_table(f, columns=["index", key])
        idx.append(torch.as_tensor(t.column("index").to_numpy()))
        vals.append(torch.as_tensor(list(t.column(key).to_pylist()), dtype=torch.float32))
    if not files:
        return None
    return torch.cat(idx).long(), torch.cat(vals)


def smolvla_camera_geometry(cfg: Any, vlm_config: Any) -> tuple[PatchGeometry, bool, tuple[int, int]]:
    """(token geometry, flip, stored (height, width)) of the regularized camera's frames, from the VLM's config
    (its vision_config.patch_size and the connector's scale_factor); see gaze_targets.smolvla_geometry."""
    shape = cfg.image_features[cfg.gaze_camera_key()].shape  # (C, H, W)
    src_hw = (int(shape[-2]), int(shape[-1]))
    patch = vlm_config.vision_config.patch_size
    geom, flip = smolvla_geometry(src_hw, cfg.resize_imgs_with_padding, patch, vlm_config.scale_factor)
    return geom, flip, src_hw


def smolvla_gaze_layers(cfg: Any, vlm_config: Any) -> tuple[list[int], str]:
    """(the VLM layer indices where the action expert attends, a sentence saying so) of the model SmolVLA builds
    from `cfg` and the VLM's config: its first num_vlm_layers text layers (all when <= 0), num_expert_layers
    expert layers (as many when <= 0)."""
    n_text = int(vlm_config.text_config.num_hidden_layers)
    n = min(cfg.num_vlm_layers, n_text) if cfg.num_vlm_layers > 0 else n_text
    layers = expert_layers(n, cfg.num_expert_layers if cfg.num_expert_layers > 0 else n)
    return layers, expert_layers_text(n, layers)


class SmolVLAGazePolicy(SmolVLAPolicy):
    config_class = SmolVLAGazeConfig
    name = "smolvla_gaze"

    def __init__(self, config: SmolVLAGazeConfig, **kwargs: Any):
        meta = kwargs.get("dataset_meta")
        vlm_config = AutoConfig.from_pretrained(
            config.vlm_model_name
        )  # the config SmolVLA builds the VLM from
        check_before_build(  # before the VLM (and its weights) is built
            config,
            meta,
            smolvla_gaze_layers(config, vlm_config),
            lambda: smolvla_camera_geometry(config, vlm_config)[0],
        )
        super().__init__(config, **kwargs)
        self.gaze_capture = SmolVLACapture(self.model, config.gaze_layers)
        self._gaze_root = getattr(meta, "root", None)
        self._gaze_table: tuple[Tensor, Tensor] | None = None
        self._gaze_geometry = None
        self._gaze_frame = gaze_frame_shape(config, meta)
        self._gaze_activity = GazeActivity(config.gaze_key)

    # ----- gaze targets --------------------------------------------------------------------------------------
    def _geometry(self) -> tuple[PatchGeometry, bool, tuple[int, int]]:
        if self._gaze_geometry is None:
            self._gaze_geometry = smolvla_camera_geometry(self.config, self.model.vlm_with_expert.config)
        return self._gaze_geometry

    def _gaze_column(self, batch: dict[str, Any]) -> Tensor:
        key = self.config.gaze_key
        if key in batch:
            return batch[key]
        if "index" in batch and self._gaze_root is not None:
            if self._gaze_table is None:
                table = _load_gaze_column(self._gaze_root, key)
                if table is None:
                    raise KeyError(f"the data set at {self._gaze_root} has no column {key!r} (gaze_key)")
                log.info("gaze: column %r read from %s (%d frames)", key, self._gaze_root, len(table[0]))
                order = torch.argsort(table[0])
                self._gaze_table = (table[0][order], table[1][order])
            index, values = self._gaze_table
            want = torch.as_tensor(batch["index"]).flatten().long().cpu()
            pos = torch.searchsorted(index, want).clamp_max(len(index) - 1)
            if not torch.equal(index[pos], want):
                raise KeyError(f"frames {want[index[pos] != want].tolist()[:5]} have no {key!r} value")
            return values[pos]
        raise KeyError(
            f"the training batch has no gaze column {key!r} (keys: {sorted(batch)}); store gaze in the data set "
            "under gaze.* and train with a *_gaze policy type (its pre-processor keeps the column)"
        )

    # ----- training ------------------------------------------------------------------------------------------
    def forward(
        self, batch: dict[str, Tensor], noise=None, time=None, reduction: str = "mean"
    ) -> tuple[Tensor, dict[str, Any]]:
        cfg = self.config
        if not self.training or cfg.gaze_weight == 0:
            return super().forward(batch, noise=noise, time=time, reduction=reduction)
        cam, cam_index = gaze_camera_index(cfg, batch)
        column = self._gaze_column(batch)
        with refusing():
            flag = gaze_valid_flag(batch, cfg.gaze_key)
        with self.gaze_capture.capture(cam_index):
            loss, loss_dict = super().forward(batch, noise=noise, time=time, reduction=reduction)
        return finish_gaze_forward(
            self, cam, cam_index, column, flag, self._geometry(), loss, loss_dict, reduction
        )
