"""The gazereg LeRobot plugin: discovery, exact attention capture, unchanged outputs, gradients, gaze targets,
and lerobot-train on the tiny LeRobot v3 fixture with a tiny offline SmolVLA."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from conftest import make_config, tiny_smolvla_gaze_flags
from gazereg.patches import PatchGeometry


def test_lerobot_discovers_the_plugin():
    """In a fresh interpreter, LeRobot's own plugin discovery (what lerobot-train runs first) registers the
    policy type; the policy and processor classes resolve by LeRobot's naming convention."""
    code = (
        "from lerobot.configs import PreTrainedConfig\n"
        "assert 'smolvla_gaze' not in PreTrainedConfig.get_known_choices()\n"
        "from lerobot.utils.import_utils import register_third_party_plugins\n"
        "register_third_party_plugins()\n"
        "from lerobot.policies.factory import get_policy_class\n"
        "cls = get_policy_class('smolvla_gaze')\n"
        "import importlib\n"
        "proc = importlib.import_module('lerobot_policy_gazereg.processor_smolvla_gaze')\n"
        "print(cls.__module__, cls.__name__, proc.make_smolvla_gaze_pre_post_processors.__name__)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.split() == [
        "lerobot_policy_gazereg.modeling_smolvla_gaze",
        "SmolVLAGazePolicy",
        "make_smolvla_gaze_pre_post_processors",
    ]


def test_config_validates_gaze_options(tiny_vlm):
    with pytest.raises(ValueError, match="under observation"):
        make_config(tiny_vlm, gaze_key="observation.gaze")
    with pytest.raises(ValueError, match="gaze_weight"):
        make_config(tiny_vlm, gaze_weight=-1.0)


def _noise_time(policy, batch):
    g = torch.Generator().manual_seed(1)
    B = batch["action"].shape[0]
    noise = torch.randn(B, policy.config.chunk_size, policy.config.max_action_dim, generator=g)
    return noise, torch.full((B,), 0.5)


def test_preprocessor_keeps_the_gaze_column(policy_and_batch):
    _, batch, raw = policy_and_batch
    torch.testing.assert_close(batch["gaze.point"], raw["gaze.point"])


def test_capture_leaves_outputs_bit_identical(policy_and_batch):
    from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy

    policy, batch, _ = policy_and_batch
    policy.train()
    noise, time = _noise_time(policy, batch)
    loss, info = policy.forward(dict(batch), noise=noise, time=time)
    plain, _ = SmolVLAPolicy.forward(policy, dict(batch), noise=noise, time=time)
    assert info["loss/action"] == float(plain.detach())  # the same float32 value: outputs bit-identical
    assert torch.isfinite(loss) and info["loss/gaze_kl"] > 0
    assert not policy.model.vlm_with_expert.__dict__.keys() & {"eager_attention_forward", "embed_image"}


def test_captured_rows_equal_the_eager_probabilities(policy_and_batch, monkeypatch):
    """The model's own softmax outputs (saved by wrapping torch's softmax during the forward) at the expert's
    query rows and the camera's image columns equal the captured rows."""
    policy, batch, _ = policy_and_batch
    policy.train()
    noise, time = _noise_time(policy, batch)
    saved = []
    softmax = torch.nn.functional.softmax

    def spy(x, *a, **k):
        out = softmax(x, *a, **k)
        saved.append(out.detach())
        return out

    import lerobot.policies.smolvla.smolvlm_with_expert as swe

    monkeypatch.setattr(swe.nn.functional, "softmax", spy)
    policy.forward(dict(batch), noise=noise, time=time)
    monkeypatch.undo()
    cap = policy.gaze_capture
    keys = cap.state.keys
    chunk = policy.config.chunk_size
    # text-model eager calls per layer (vision tower uses its own attention): joint layers 1 call, cross layers 2
    calls, i = {}, 0
    for layer in range(4):
        n = 1 if layer % policy.config.self_attn_every_n_layers == 0 else 2
        calls[layer] = saved[i + n - 1]  # the expert's call is the last one of the layer
        i += n
    assert i == len(saved)
    for layer in cap.layers:
        probs = calls[layer][:, :, -chunk:][..., keys]
        torch.testing.assert_close(cap.state.probe.rows(layer), probs, rtol=0, atol=1e-6)


def test_gaze_gradient_reaches_the_action_expert(policy_and_batch):
    policy, batch, _ = policy_and_batch
    policy.train()
    noise, time = _noise_time(policy, batch)
    with policy.gaze_capture.capture(camera_index=0):
        from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy

        SmolVLAPolicy.forward(policy, dict(batch), noise=noise, time=time)
    att = policy.gaze_capture.attention()
    target = torch.zeros_like(att)
    target[:, 0] = 1
    kl = (target * (target.clamp_min(1e-8).log() - att.clamp_min(1e-8).log())).sum(-1).mean()
    kl.backward()
    layer = policy.model.vlm_with_expert.lm_expert.layers[policy.gaze_capture.layers[-1]]
    assert layer.self_attn.q_proj.weight.grad.abs().sum() > 0


def test_wrong_grid_is_an_error_naming_both(policy_and_batch):
    policy, batch, _ = policy_and_batch
    policy.train()
    policy._gaze_geometry = (PatchGeometry(input_hw=(64, 64), patch_size=32), False, (64, 64))
    with pytest.raises(ValueError, match=r"produced 16 image tokens but its geometry \(2, 2\)"):
        policy.forward(dict(batch))


def test_gaze_layers_must_have_an_expert(tiny_vlm, dataset):
    from lerobot.policies import make_policy

    with pytest.raises(ValueError, match=r"expert attends at VLM layers \[0, 1, 2, 3\]"):
        make_policy(make_config(tiny_vlm, gaze_layers=[7]), ds_meta=dataset.meta)


def test_gaze_targets_follow_smolvla_left_top_padding():
    from lerobot_policy_gazereg.gaze_targets import gaze_distribution, smolvla_geometry

    # a 32x64 (h, w) frame fitted into 64x64 with padding on the top: content in rows 32..63 of the input
    geom, flip = smolvla_geometry((32, 64), (64, 64), patch_size=8, pixel_shuffle=2)  # 4x4 token grid
    assert flip and geom.grid_hw == (4, 4)
    pts = torch.tensor([[0.1, 0.1], [0.9, 0.9], [float("nan"), 0.5]])
    dist, valid = gaze_distribution(pts, geom, flip, sigma_frac=0.02, src_hw=(32, 64))
    assert valid.tolist() == [True, True, False]
    assert dist[0].argmax() == 2 * 4 + 0  # top-left of the content: token row 2, column 0
    assert dist[1].argmax() == 3 * 4 + 3
    assert dist[0][:8].sum() < 1e-4  # the padding rows get (almost) nothing
    # a square frame: no padding at all
    geom2, flip2 = smolvla_geometry((64, 64), (64, 64), patch_size=8, pixel_shuffle=2)
    assert not flip2 and geom2.resize == "stretch"
    # precomputed distributions on the token grid pass through
    d = torch.rand(2, 16)
    out, ok = gaze_distribution(d, geom2, False, 0.05, (64, 64))
    assert ok.all() and torch.allclose(out, d / d.sum(-1, keepdim=True), atol=1e-4)


def test_gaze_column_is_read_from_the_data_set_when_the_batch_lacks_it(policy_and_batch):
    policy, batch, raw = policy_and_batch
    b = {k: v for k, v in batch.items() if k != "gaze.point"}
    torch.testing.assert_close(policy._gaze_column(b), raw["gaze.point"])
    policy._gaze_root = None
    with pytest.raises(KeyError, match="no gaze column 'gaze.point'"):
        policy._gaze_column(b)


def _lerobot_train(tmp_path: Path, dataset_root: Path, tiny_vlm: Path, steps: int, *extra: str):
    exe = Path(sys.executable).with_name("lerobot-train")
    cmd = [
        str(exe),
        *tiny_smolvla_gaze_flags(tiny_vlm),
        "--policy.gaze_weight=1.0",
        "--policy.gaze_camera=observation.images.front",
        "--policy.gaze_layers=[1,3]",
        "--policy.optimizer_lr=0.003",
        "--policy.scheduler_warmup_steps=0",
        "--dataset.repo_id=local/lerobot_v3_tiny",
        f"--dataset.root={dataset_root}",
        "--dataset.episodes=[0]",  # 20 frames = one batch: the same batch at every step
        "--dataset.video_backend=pyav",
        "--batch_size=20",
        f"--steps={steps}",
        "--log_freq=1",
        f"--save_freq={steps}",
        "--num_workers=0",
        "--wandb.enable=false",
        f"--output_dir={tmp_path / 'run'}",
        *extra,
    ]
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
    return subprocess.run(cmd, capture_output=True, text=True, timeout=900, env=env)


def test_lerobot_train_logs_a_falling_gaze_term(tmp_path, dataset_root, tiny_vlm):
    r = _lerobot_train(tmp_path, dataset_root, tiny_vlm, steps=8)
    log = r.stdout + r.stderr
    assert r.returncode == 0, log[-4000:]
    kls = [float(x) for x in re.findall(r"loss/gaze_kl:([-0-9.naif]+)", log)]
    assert len(kls) == 8, log[-3000:]
    assert all(math.isfinite(k) for k in kls), kls
    assert kls[-1] < kls[0], kls
    assert "loss/action:" in log and "gaze/weight:1.000" in log
    # the checkpoint: the gaze policy type with its options, and exactly SmolVLA's parameters
    ckpt = tmp_path / "run" / "checkpoints" / "last" / "pretrained_model"
    cfg = json.loads((ckpt / "config.json").read_text())
    assert cfg["type"] == "smolvla_gaze" and cfg["gaze_layers"] == [1, 3] and cfg["gaze_weight"] == 1.0
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig
    from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy
    from safetensors.torch import load_file

    state = load_file(ckpt / "model.safetensors")
    plain_cfg = SmolVLAConfig(**{k: v for k, v in cfg.items() if k in SmolVLAConfig.__dataclass_fields__})
    plain_cfg.input_features = {
        "observation.images.front": PolicyFeature(FeatureType.VISUAL, (3, 64, 64)),
        "observation.state": PolicyFeature(FeatureType.STATE, (4,)),
    }
    plain_cfg.output_features = {"action": PolicyFeature(FeatureType.ACTION, (4,))}
    plain = SmolVLAPolicy(plain_cfg)
    assert set(state) == set(plain.state_dict())
