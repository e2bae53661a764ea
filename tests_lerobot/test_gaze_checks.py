"""Refusals of the gaze plugin (issue 33): a gaze run whose term could never be active, a gaze column of a shape
the plugin does not read, a bad gaze_camera / gaze_key found from the data set's features before any model is
built, and option errors that reach the lerobot-train user as one line naming the option (exit status 2)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from conftest import make_config, tiny_smolvla_gaze_flags

GAZE_TYPES = ["smolvla_gaze", "pi0_gaze", "pi05_gaze"]


def _gaze_config(policy_type: str, **gaze):
    """A gaze config of each type with the fixture's features set (no model is built)."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot_policy_gazereg import PI0GazeConfig, PI05GazeConfig, SmolVLAGazeConfig

    cls = {"smolvla_gaze": SmolVLAGazeConfig, "pi0_gaze": PI0GazeConfig, "pi05_gaze": PI05GazeConfig}[
        policy_type
    ]
    cfg = cls(**{"gaze_weight": 1.0, **gaze})
    cfg.input_features = {
        "observation.images.front": PolicyFeature(FeatureType.VISUAL, (3, 64, 64)),
        "observation.state": PolicyFeature(FeatureType.STATE, (4,)),
    }
    cfg.output_features = {"action": PolicyFeature(FeatureType.ACTION, (4,))}
    return cfg


def _copy_with_gaze(src: Path, dst: Path, key: str, values: np.ndarray, shape: tuple[int, ...]) -> Path:
    """A copy of the LeRobot v3 data set at `src` whose column `key` holds `values` (N, *shape) float32 (added to
    info.json's features when new)."""
    import json

    import pyarrow as pa
    import pyarrow.parquet as pq

    shutil.copytree(src, dst)
    (f,) = sorted((dst / "data").glob("*/*.parquet"))
    table = pq.read_table(f)
    if key in table.column_names:  # the same arrow type: the data set's own schema metadata still holds
        i = table.column_names.index(key)
        table = table.set_column(i, key, pa.array(values.tolist(), type=table.schema.field(i).type))
    else:
        typ = pa.float32()
        for d in reversed(shape):
            typ = pa.list_(typ, d)
        table = table.append_column(key, pa.array(values.tolist(), type=typ))
    pq.write_table(table, f)
    info = json.loads((dst / "meta" / "info.json").read_text())
    info["features"][key] = {"dtype": "float32", "shape": list(shape), "names": None}
    (dst / "meta" / "info.json").write_text(json.dumps(info, indent=4))
    return dst


def _meta(root: Path, **extra_features) -> SimpleNamespace:
    """Stand-in for LeRobotDatasetMetadata: the data set's features (plus `extra_features`) and root."""
    import json

    features = json.loads((root / "meta" / "info.json").read_text())["features"]
    for v in features.values():
        v["shape"] = tuple(v["shape"])
    return SimpleNamespace(root=root, features={**features, **extra_features})


N_FRAMES = 66
UNUSABLE = {
    "nan points": ("gaze.point", np.full((N_FRAMES, 2), np.nan), (2,)),
    "points outside the image": ("gaze.point", np.tile([[1.5, -0.2]], (N_FRAMES, 1)), (2,)),
    "heatmaps <= 0": ("gaze.front.heatmap", -np.ones((N_FRAMES, 8, 8)), (8, 8)),
}


@pytest.mark.parametrize("case", list(UNUSABLE))
def test_a_gaze_column_without_a_usable_frame_is_refused(case, tmp_path, dataset_root):
    from lerobot_policy_gazereg.gaze_data import check_gaze_data

    key, values, shape = UNUSABLE[case]
    root = _copy_with_gaze(dataset_root, tmp_path / "ds", key, values.astype(np.float32), shape)
    cfg = _gaze_config("smolvla_gaze", gaze_key=key, gaze_camera="observation.images.front")
    with pytest.raises(
        ValueError, match=rf"gaze_key={key}: none of the {N_FRAMES} frames .* has usable gaze"
    ):
        check_gaze_data(cfg, _meta(root))
    # one usable frame is enough; gaze_weight 0 (the plain policy) checks nothing
    values = values.copy()
    values[7] = 0.5
    check_gaze_data(cfg, _meta(_copy_with_gaze(dataset_root, tmp_path / "ok", key, values, shape)))
    check_gaze_data(_gaze_config("smolvla_gaze", gaze_key=key, gaze_weight=0.0), _meta(root))


def test_the_flag_column_counts_in_the_data_check(tmp_path, dataset_root):
    """Heatmaps with mass everywhere but every frame flagged false in gaze.front.valid: no usable frame."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from lerobot_policy_gazereg.gaze_data import check_gaze_data

    root = _copy_with_gaze(
        dataset_root, tmp_path / "ds", "gaze.front.heatmap", np.ones((N_FRAMES, 4, 4)), (4, 4)
    )
    (f,) = sorted((root / "data").glob("*/*.parquet"))
    pq.write_table(pq.read_table(f).append_column("gaze.front.valid", pa.array([False] * N_FRAMES)), f)
    flag = {"gaze.front.valid": {"dtype": "bool", "shape": (1,)}}
    cfg = _gaze_config("smolvla_gaze", gaze_key="gaze.front.heatmap")
    with pytest.raises(ValueError, match=r"none of the 66 frames .*flagged false in gaze.front.valid"):
        check_gaze_data(cfg, _meta(root, **flag))


@pytest.mark.parametrize("policy_type", GAZE_TYPES)
@pytest.mark.parametrize(
    ("options", "extra", "message"),
    [
        (
            {"gaze_key": "gaze.pt"},
            {},
            r"gaze_key=gaze.pt: the data set has no such column \(its gaze columns: gaze.point\)",
        ),
        ({"gaze_camera": "observation.images.top"}, {}, r"gaze_camera=observation.images.top: not one of"),
        (
            {"gaze_key": "gaze.front.heatmap"},
            {"gaze.front.heatmap": {"dtype": "float32", "shape": (2, 8, 8)}},
            r"gaze_key=gaze.front.heatmap: the column's value per frame has shape \(2, 8, 8\); accepted: \(2,\) a "
            r"\(u, v\) point, \(h, w\) a heatmap",
        ),
    ],
)
def test_the_features_are_checked_before_the_policy_is_built(
    policy_type, options, extra, message, dataset_root, monkeypatch
):
    """lerobot's make_policy hands the data set's features to the config (set_dataset_feature_metadata) before
    it builds the policy: a bad gaze_key, gaze_camera or column shape is refused there, for every gaze type, and
    the policy class (which would build the model and load its weights) is never called."""
    from lerobot.policies import factory, make_policy

    def never(*a, **k):
        raise AssertionError("the policy was built before the gaze features were checked")

    monkeypatch.setattr(factory, "get_policy_class", lambda name: never)
    cfg = _gaze_config(policy_type, **options)
    cfg.input_features = {}  # make_policy derives them from the data set
    with pytest.raises(ValueError, match=message):
        make_policy(cfg, ds_meta=_meta(dataset_root, **extra))


def test_a_per_frame_shape_the_data_set_does_not_declare_is_refused_in_forward(policy_and_batch):
    """A (B, 2, 8, 8) batch for a column the data set declares (2,) is refused, not read as a 2-frame history;
    without a data set, (2, 8, 8) per frame is refused as a shape the plugin does not read."""
    policy, batch, _ = policy_and_batch
    policy.train()
    b = dict(batch)
    b["gaze.point"] = torch.rand(4, 2, 8, 8)
    with pytest.raises(
        ValueError, match=r"gaze_key=gaze.point: the batch holds values of shape \(2, 8, 8\) per "
    ):
        policy.forward(dict(b))
    policy._gaze_frame = None
    with pytest.raises(ValueError, match=r"value per frame has shape \(2, 8, 8\); accepted: \(2,\)"):
        policy.forward(dict(b))


def test_a_gaze_term_never_active_in_training_stops_the_run(policy_and_batch, monkeypatch):
    """All-NaN gaze in every training batch: once GazeActivity's limit of frames has gone by without a usable
    one, the forward refuses; one usable frame before that disarms it."""
    from lerobot_policy_gazereg.gaze_common import GazeActivity

    policy, batch, _ = policy_and_batch
    policy.train()
    policy._gaze_activity = GazeActivity("gaze.point", limit=10)
    nan = dict(batch)
    nan["gaze.point"] = torch.full_like(batch["gaze.point"], float("nan"))  # 4 frames per batch
    _, info = policy.forward(dict(nan))
    assert info["gaze/valid_frac"] == 0.0
    policy.forward(dict(nan))
    with pytest.raises(
        ValueError, match=r"gaze_key=gaze.point: none of the first 12 training frames had usable gaze"
    ):
        policy.forward(dict(nan))
    policy._gaze_activity = GazeActivity("gaze.point", limit=10)
    one = dict(nan)
    one["gaze.point"] = nan["gaze.point"].clone()
    one["gaze.point"][0] = 0.5
    policy.forward(dict(one))
    for _ in range(4):
        policy.forward(dict(nan))


def test_option_errors_name_the_option(tiny_vlm):
    from lerobot_policy_gazereg.errors import GazeUsageError

    with pytest.raises(GazeUsageError, match=r"^gaze_weight: must be a finite number >= 0, got -0.5$"):
        make_config(tiny_vlm, gaze_weight=-0.5)
    with pytest.raises(GazeUsageError, match=r"^gaze_divergence: must be forward, reverse or js"):
        make_config(tiny_vlm, gaze_divergence="kl")


# ----- checks against the model, before it is built --------------------------------------------------------------
class _Built(Exception):
    """Raised in place of building the base policy's model: the gaze policy's checks all passed."""


def _tiny_gaze_config(policy_type: str, tiny_vlm: Path, **gaze):
    """A tiny gaze config of each type (SmolVLA over `tiny_vlm`, 4 VLM layers; pi0/pi05 at lerobot's sizes:
    18 layers, 14 px patches; 16 image tokens either way) with the fixture's features set."""
    from lerobot_policy_gazereg.testing import tiny_pi_args, tiny_smolvla_args

    base = tiny_smolvla_args(tiny_vlm) if policy_type == "smolvla_gaze" else tiny_pi_args()
    return _gaze_config(policy_type, **base, gaze_camera="observation.images.front", **gaze)


def _never_built(monkeypatch, policy_type: str):
    """The gaze policy class of `policy_type`, its base policy's __init__ raising _Built: only what the gaze
    policy checks before it builds its model runs."""
    from lerobot_policy_gazereg.modeling_pi0_gaze import PI0GazePolicy
    from lerobot_policy_gazereg.modeling_pi05_gaze import PI05GazePolicy
    from lerobot_policy_gazereg.modeling_smolvla_gaze import SmolVLAGazePolicy

    cls = {"smolvla_gaze": SmolVLAGazePolicy, "pi0_gaze": PI0GazePolicy, "pi05_gaze": PI05GazePolicy}[
        policy_type
    ]

    def build(self, *a, **k):
        raise _Built

    monkeypatch.setattr(_base_policy(cls), "__init__", build)
    return cls


def _base_policy(cls):
    """The lerobot policy class a gaze policy class extends (SmolVLAPolicy, PI0Policy, PI05Policy)."""
    return next(c for c in cls.__mro__[1:] if c.__module__.startswith("lerobot.policies."))


LAYER_RANGES = {
    "smolvla_gaze": "the VLM has 4 layers and the action expert attends at VLM layers [0, 1, 2, 3]",
    "pi0_gaze": "the model has 18 layers, 0..17",
    "pi05_gaze": "the model has 18 layers, 0..17",
}


@pytest.mark.parametrize("policy_type", GAZE_TYPES)
def test_gaze_layers_out_of_range_are_refused_before_the_model_is_built(policy_type, tiny_vlm, monkeypatch):
    """The issue: a layer index beyond the model's depth raised a traceback from the capture, after the model
    (and SmolVLA's VLM weights) was built. Now one GazeUsageError names the option, the bad indices and the
    model's layers before the base policy's __init__ runs; valid layers go on to build it."""
    from lerobot_policy_gazereg.errors import GazeUsageError

    cls = _never_built(monkeypatch, policy_type)
    cfg = _tiny_gaze_config(policy_type, tiny_vlm, gaze_layers=[1, 40, -1])
    want = f"gaze_layers: [40, -1] out of range: {LAYER_RANGES[policy_type]}"
    with pytest.raises(GazeUsageError, match=f"^{re.escape(want)}$"):
        cls(cfg)
    with pytest.raises(GazeUsageError, match=r"^gaze_layers: names no layer: "):
        cls(_tiny_gaze_config(policy_type, tiny_vlm, gaze_layers=[]))
    with pytest.raises(_Built):
        cls(_tiny_gaze_config(policy_type, tiny_vlm, gaze_layers=[1, 3]))


@pytest.mark.parametrize("policy_type", GAZE_TYPES)
def test_a_token_distribution_not_on_the_camera_grid_is_refused_before_the_model_is_built(
    policy_type, tiny_vlm, tmp_path, dataset_root, monkeypatch
):
    """The issue: a (n,) token-distribution column with n != the camera's token count was refused only at the
    first training forward. Now the policy refuses it before its model is built, naming the column, n and the
    camera's token count; a column of the grid's 16 values goes on to build it."""
    from lerobot_policy_gazereg.errors import GazeUsageError

    cls = _never_built(monkeypatch, policy_type)
    cfg = _tiny_gaze_config(policy_type, tiny_vlm, gaze_key="gaze.tokens")
    root = _copy_with_gaze(dataset_root, tmp_path / "ds50", "gaze.tokens", np.ones((N_FRAMES, 50)), (50,))
    want = (
        "gaze_key=gaze.tokens: the column holds 50 values per frame, read as a distribution over image tokens, "
        "but camera observation.images.front has 16 image tokens (4x4 grid); store one value per token, "
        "row-major"
    )
    with pytest.raises(GazeUsageError, match=f"^{re.escape(want)}$"):
        cls(cfg, dataset_meta=_meta(root))
    root = _copy_with_gaze(dataset_root, tmp_path / "ds16", "gaze.tokens", np.ones((N_FRAMES, 16)), (16,))
    with pytest.raises(_Built):
        cls(cfg, dataset_meta=_meta(root))
    with pytest.raises(_Built):  # the plain policy checks no column
        cls(_tiny_gaze_config(policy_type, tiny_vlm, gaze_key="gaze.tokens", gaze_weight=0.0))


def test_smolvla_checks_the_model_it_then_builds(policy_and_batch):
    """The layers and token geometry checked before the build (from the VLM's config) are the built model's."""
    from lerobot_policy_gazereg.modeling_smolvla_gaze import smolvla_camera_geometry, smolvla_gaze_layers
    from transformers import AutoConfig

    policy, _, _ = policy_and_batch
    vlm = AutoConfig.from_pretrained(policy.config.vlm_model_name)
    assert smolvla_gaze_layers(policy.config, vlm)[0] == policy.gaze_capture.expert_layers == [0, 1, 2, 3]
    assert smolvla_camera_geometry(policy.config, vlm) == policy._geometry()
    assert policy._geometry()[0].n_patches == 16


@pytest.mark.parametrize("policy_type", ["pi0_gaze", "pi05_gaze"])
def test_pi_checks_the_model_it_then_builds(policy_type, tiny_vlm):
    """lerobot_model_shape (read from lerobot's configs, tiny ones here: 3 layers, 8 px patches) is the built
    model's layer count and patch size."""
    from lerobot_policy_gazereg.modeling_pi0_gaze import PI0GazePolicy
    from lerobot_policy_gazereg.modeling_pi05_gaze import PI05GazePolicy
    from lerobot_policy_gazereg.testing import tiny_pi_models

    gp = PI0GazePolicy if policy_type == "pi0_gaze" else PI05GazePolicy
    with tiny_pi_models(depth=3, patch_size=8):
        cfg = _tiny_gaze_config(policy_type, tiny_vlm, gaze_layers=[2])
        policy = gp(cfg)
        patch = policy.model.paligemma_with_expert.paligemma.config.vision_config.patch_size
        assert gp.lerobot_model_shape(cfg) == (policy.gaze_capture.depth, patch) == (3, 8)


# ----- the real lerobot-train ----------------------------------------------------------------------------------
def _lerobot_train(
    tmp_path: Path, dataset_root: Path, tiny_vlm: Path, *extra: str
) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).with_name("lerobot-train")
    cmd = [
        str(exe),
        *tiny_smolvla_gaze_flags(tiny_vlm),
        "--policy.gaze_camera=observation.images.front",
        "--dataset.repo_id=local/lerobot_v3_tiny",
        f"--dataset.root={dataset_root}",
        "--dataset.video_backend=pyav",
        "--batch_size=4",
        "--steps=2",
        "--log_freq=1",
        "--save_freq=2",
        "--num_workers=0",
        "--wandb.enable=false",
        f"--output_dir={tmp_path / 'run'}",
        *extra,
    ]
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env)


def _error_lines(r: subprocess.CompletedProcess) -> list[str]:
    """The lines that report an error (`...error: ...`, `ValueError: ...`), after the torchcodec load failure
    lerobot logs at import where torchcodec cannot load."""
    log = (r.stdout + r.stderr).split("[end of libtorchcodec loading traceback]")[-1]
    return [line for line in log.splitlines() if re.search(r"error:", line, re.IGNORECASE)]


def test_lerobot_train_refuses_a_gaze_column_without_a_usable_frame(tmp_path, dataset_root, tiny_vlm):
    """The issue: all-NaN gaze trained to exit 0 with gaze/valid_frac 0.000 at every step. Now lerobot-train
    stops before the model is built, with one line naming the column, and no checkpoint is written."""
    root = _copy_with_gaze(
        dataset_root, tmp_path / "ds", "gaze.point", np.full((N_FRAMES, 2), np.nan, np.float32), (2,)
    )
    r = _lerobot_train(tmp_path, root, tiny_vlm)
    log = r.stdout + r.stderr
    assert r.returncode == 2, log[-3000:]
    assert _error_lines(r) == [
        f"lerobot-train: error: --policy.gaze_key=gaze.point: none of the {N_FRAMES} frames of the data set at "
        f"{root} has usable gaze: every (u, v) is NaN or outside [0, 1]^2, so the gaze term would never be "
        "active; fix the column or set --policy.gaze_weight=0"
    ], log[-3000:]
    assert "Traceback" not in log.split("[end of libtorchcodec loading traceback]")[-1], log[-3000:]
    assert "gaze_kl" not in log and not (tmp_path / "run" / "checkpoints").exists()


@pytest.mark.parametrize(
    ("option", "line"),
    [
        ("--policy.gaze_weight=-0.5", "--policy.gaze_weight: must be a finite number >= 0, got -0.5"),
        ("--policy.gaze_key=observation.state", "--policy.gaze_key=observation.state: the column is under "),
    ],
)
def test_lerobot_train_names_the_bad_gaze_option(option, line, tmp_path, dataset_root, tiny_vlm):
    """The issue: draccus printed "Couldn't instantiate class SmolVLAGazeConfig" without the field."""
    r = _lerobot_train(tmp_path, dataset_root, tiny_vlm, option)
    log = r.stdout + r.stderr
    assert r.returncode == 2, log[-3000:]
    (err,) = _error_lines(r)
    assert err.startswith(f"lerobot-train: error: {line}"), log[-3000:]
    assert "Couldn't instantiate" not in log


@pytest.mark.parametrize("case", ["layers", "tokens"])
def test_lerobot_train_refuses_what_the_model_cannot_take(case, tmp_path, dataset_root, tiny_vlm):
    """The issues: --policy.gaze_layers beyond the VLM's layers showed a traceback, and a token-distribution column
    of the wrong length was refused only at the first training forward. Now lerobot-train stops while the policy
    is built, with one line naming the option or column, exit status 2, no traceback, no training step."""
    if case == "layers":
        root, extra = dataset_root, ["--policy.gaze_layers=[1,9]"]
        line = (
            "--policy.gaze_layers: [9] out of range: the VLM has 4 layers and the action expert attends at VLM "
            "layers [0, 1, 2, 3]"
        )
    else:
        root = _copy_with_gaze(dataset_root, tmp_path / "ds", "gaze.tokens", np.ones((N_FRAMES, 50)), (50,))
        extra = ["--policy.gaze_key=gaze.tokens"]
        line = (
            "--policy.gaze_key=gaze.tokens: the column holds 50 values per frame, read as a distribution over "
            "image tokens, but camera observation.images.front has 16 image tokens (4x4 grid); store one value "
            "per token, row-major"
        )
    r = _lerobot_train(tmp_path, root, tiny_vlm, *extra)
    log = r.stdout + r.stderr
    assert r.returncode == 2, log[-3000:]
    assert _error_lines(r) == [f"lerobot-train: error: {line}"], log[-3000:]
    assert "Traceback" not in log.split("[end of libtorchcodec loading traceback]")[-1], log[-3000:]
    assert "Creating policy" in log and "Creating optimizer" not in log, log[-3000:]  # refused in make_policy
    assert "gaze_kl" not in log and not (tmp_path / "run" / "checkpoints").exists()


def test_the_readme_states_the_inactivity_limit():
    from lerobot_policy_gazereg.gaze_common import INACTIVE_FRAMES_LIMIT

    readme = (Path(__file__).resolve().parents[1] / "lerobot_plugin" / "README.md").read_text()
    assert f"the first {INACTIVE_FRAMES_LIMIT:,} training frames" in readme
