"""`pi0_gaze` and `pi05_gaze`: the same state dict and inference as lerobot's pi0 / pi05, exact attention capture,
a gaze term with a gradient into the action expert, and the real lerobot-train (train, resume, --policy.path) on
the tiny LeRobot v3 fixture, with tiny offline PaliGemma models (lerobot_policy_gazereg.testing)."""

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

KINDS = ["pi0", "pi05"]
CAM = "observation.images.front"
WRIST = "observation.images.wrist"


def _classes(kind: str):
    """(base config, base policy, gaze config, gaze policy) classes of one kind."""
    if kind == "pi0":
        from lerobot.policies.pi0.configuration_pi0 import PI0Config as C
        from lerobot.policies.pi0.modeling_pi0 import PI0Policy as P
        from lerobot_policy_gazereg.configuration_pi0_gaze import PI0GazeConfig as GC
        from lerobot_policy_gazereg.modeling_pi0_gaze import PI0GazePolicy as GP
    else:
        from lerobot.policies.pi05.configuration_pi05 import PI05Config as C
        from lerobot.policies.pi05.modeling_pi05 import PI05Policy as P
        from lerobot_policy_gazereg.configuration_pi05_gaze import PI05GazeConfig as GC
        from lerobot_policy_gazereg.modeling_pi05_gaze import PI05GazePolicy as GP
    return C, P, GC, GP


def test_lerobot_discovers_pi0_gaze_and_pi05_gaze():
    """In a fresh interpreter, LeRobot's own plugin discovery (what lerobot-train runs first) registers both types;
    policy and processor resolve by LeRobot's naming convention (the issue: `pi0_gaze` was an invalid choice)."""
    code = (
        "from lerobot.configs import PreTrainedConfig\n"
        "assert 'pi0_gaze' not in PreTrainedConfig.get_known_choices()\n"
        "from lerobot.utils.import_utils import register_third_party_plugins\n"
        "register_third_party_plugins()\n"
        "from lerobot.policies.factory import get_policy_class, make_policy_config\n"
        "from lerobot.policies.factory import _make_processors_from_policy_config as mk\n"
        "import importlib\n"
        "for t in ('pi0_gaze', 'pi05_gaze'):\n"
        "    cls = get_policy_class(t)\n"
        "    mod = importlib.import_module(make_policy_config(t).__class__.__module__.replace('configuration_', "
        "'processor_'))\n"
        "    print(cls.__module__, cls.__name__, getattr(mod, f'make_{t}_pre_post_processors').__name__)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert r.stdout.split() == [
        "lerobot_policy_gazereg.modeling_pi0_gaze", "PI0GazePolicy", "make_pi0_gaze_pre_post_processors",
        "lerobot_policy_gazereg.modeling_pi05_gaze", "PI05GazePolicy", "make_pi05_gaze_pre_post_processors",
    ]  # fmt: skip


@pytest.fixture(scope="module")
def tiny():
    from lerobot_policy_gazereg.testing import tiny_pi_models

    with tiny_pi_models():
        yield
    _BUILT.clear()


def _features(cfg):
    from lerobot.configs.types import FeatureType, PolicyFeature

    cfg.input_features = {
        CAM: PolicyFeature(FeatureType.VISUAL, (3, 64, 64)),
        WRIST: PolicyFeature(FeatureType.VISUAL, (3, 64, 64)),
        "observation.state": PolicyFeature(FeatureType.STATE, (4,)),
    }
    cfg.output_features = {"action": PolicyFeature(FeatureType.ACTION, (4,))}
    return cfg


_BUILT: dict = {}


def _policies(kind: str, **gaze):
    """(base policy, gaze policy) built from the same tiny config, the gaze one holding the base's weights
    (cached per kind and options: the models are built once per module)."""
    from lerobot_policy_gazereg.testing import tiny_pi_args

    key = (kind, repr(sorted(gaze.items())))
    if key not in _BUILT:
        C, P, GC, GP = _classes(kind)
        torch.manual_seed(0)
        base = P(_features(C(**tiny_pi_args())))
        opts = {"gaze_weight": 1.0, "gaze_camera": WRIST, "gaze_layers": [0, 1], **gaze}
        policy = GP(_features(GC(**tiny_pi_args(), **opts)))
        policy.load_state_dict(base.state_dict())
        _BUILT[key] = (base, policy)
    return _BUILT[key]


def _batch(dataset, n: int = 4) -> dict:
    """A model-ready batch of the fixture's first frames: raw images and state, random language tokens."""
    raw = torch.utils.data.default_collate([dataset[i] for i in range(n)])
    g = torch.Generator().manual_seed(0)
    batch = {k: v for k, v in raw.items() if isinstance(v, torch.Tensor)}
    batch["observation.language.tokens"] = torch.randint(4, 40, (n, 32), generator=g)
    batch["observation.language.attention_mask"] = torch.ones(n, 32, dtype=torch.bool)
    return batch


@pytest.mark.parametrize("kind", KINDS)
def test_same_state_dict_and_bit_identical_outputs(kind, tiny, dataset):
    base, policy = _policies(kind)
    sd, gsd = base.state_dict(), policy.state_dict()
    assert {k: v.shape for k, v in sd.items()} == {k: v.shape for k, v in gsd.items()}
    batch = _batch(dataset)
    # select_action (inference) bit-identical
    out = []
    for p in (base, policy):
        p.reset()
        torch.manual_seed(3)
        out.append(p.select_action(dict(batch)))
    assert torch.equal(out[0], out[1])
    # the training forward: the action loss is bit-identical with the capture running
    base.train(), policy.train()
    torch.manual_seed(4)
    plain, _ = base.forward(dict(batch))
    torch.manual_seed(4)
    loss, info = policy.forward(dict(batch))
    assert info["loss/action"] == float(plain.detach())
    assert math.isfinite(info["loss/gaze_kl"]) and info["loss/gaze_kl"] > 0 and torch.isfinite(loss)
    assert info["gaze/valid_frac"] == 1.0 and 0 < info["gaze/patch_mass"] < 1


@pytest.mark.parametrize("kind", KINDS)
def test_captured_rows_equal_the_eager_probabilities(kind, tiny, dataset, monkeypatch):
    from transformers.models.gemma import modeling_gemma

    _, policy = _policies(kind)  # the gaze camera is the wrist, the second camera
    policy.train()
    saved = []
    eager = modeling_gemma.eager_attention_forward

    def spy(*a, **k):
        out, weights = eager(*a, **k)
        saved.append(weights.detach())
        return out, weights

    monkeypatch.setattr(modeling_gemma, "eager_attention_forward", spy)
    policy.forward(_batch(dataset))
    monkeypatch.undo()
    cap = policy.gaze_capture
    assert len(saved) == cap.depth == 2 and cap.image_tokens == [16, 16]
    assert cap.state.keys.tolist() == list(range(16, 32))
    chunk = policy.config.chunk_size
    for layer in cap.layers:
        probs = saved[layer][:, :, -chunk:][..., cap.state.keys]
        torch.testing.assert_close(cap.state.probe.rows(layer), probs, rtol=0, atol=1e-6)


@pytest.mark.parametrize("kind", KINDS)
def test_gaze_gradient_reaches_the_action_expert(kind, tiny, dataset):
    _, P, _, _ = _classes(kind)
    _, policy = _policies(kind)
    policy.train()
    with policy.gaze_capture.capture(camera_index=1, n_queries=policy.config.chunk_size):
        P.forward(policy, _batch(dataset))
    att = policy.gaze_capture.attention()
    target = torch.zeros_like(att)
    target[:, 0] = 1
    kl = (target * (target.clamp_min(1e-8).log() - att.clamp_min(1e-8).log())).sum(-1).mean()
    kl.backward()
    expert = policy.model.paligemma_with_expert.gemma_expert.model.layers[policy.gaze_capture.layers[-1]]
    assert expert.self_attn.q_proj.weight.grad.abs().sum() > 0


@pytest.mark.parametrize("kind", KINDS)
def test_gradient_checkpointing_gives_the_same_loss_and_gradients(kind, tiny, dataset, monkeypatch):
    """With lerobot's gradient checkpointing the layers are recomputed in backward (counted here) and every
    parameter's gradient, the gaze term's included, equals the one without it (the issue: a CheckpointError or
    a gaze term without gradient)."""
    from transformers.models.gemma import modeling_gemma

    _, policy = _policies(kind)
    policy.train()
    batch, grads, losses, forward_calls, recomputed = _batch(dataset), [], [], [], []
    eager = modeling_gemma.eager_attention_forward
    calls = [0]

    def counting(*a, **k):
        calls[0] += 1
        return eager(*a, **k)

    monkeypatch.setattr(modeling_gemma, "eager_attention_forward", counting)
    for checkpointing in (False, True):
        if checkpointing:
            policy.model.gradient_checkpointing_enable()
        policy.zero_grad(set_to_none=True)
        torch.manual_seed(4)
        calls[0] = 0
        loss, info = policy.forward(dict(batch))
        forward_calls.append(calls[0])
        calls[0] = 0
        loss.backward()
        recomputed.append(calls[0])
        grads.append({n: p.grad.clone() for n, p in policy.named_parameters() if p.grad is not None})
        losses.append((float(loss.detach()), info["loss/gaze_kl"]))
    policy.model.gradient_checkpointing_disable()
    # the layers are run again in backward (lerobot's checkpointing recomputes each layer's attention at least
    # once, the captured layers among them), and not at all without checkpointing
    assert recomputed[0] == 0 and recomputed[1] >= forward_calls[1] == policy.gaze_capture.depth
    assert losses[0] == losses[1] and losses[0][1] > 0
    assert grads[0].keys() == grads[1].keys()
    for name, g in grads[0].items():
        torch.testing.assert_close(grads[1][name], g, rtol=1e-6, atol=1e-7, msg=name)


def test_gaze_options_are_validated(tiny):
    _, _, GC, _ = _classes("pi0")
    with pytest.raises(ValueError, match="under observation"):
        GC(gaze_key="observation.gaze")
    with pytest.raises(ValueError, match="compile_model"):
        GC(compile_model=True)
    assert GC(gradient_checkpointing=True).gradient_checkpointing  # works: see the test below
    with pytest.raises(ValueError, match=r"gaze_layers: \[2\] out of range: the model has 2 layers, 0\.\.1"):
        _policies("pi05", gaze_layers=[2])


def test_gaze_options_are_validated_as_for_smolvla(tiny):
    """One validation for every gaze type (gaze_common.validate_gaze_options)."""
    for kind in KINDS:
        _, _, GC, _ = _classes(kind)
        with pytest.raises(ValueError, match="gaze_weight: must be a finite"):
            GC(gaze_weight=float("nan"))
        with pytest.raises(ValueError, match="gaze_target_mass"):
            GC(gaze_target_mass=1.5)


@pytest.mark.parametrize("kind", KINDS)
def test_target_mass_variant(kind, tiny, dataset):
    """gaze_target_mass=m: the term is gazereg's mass loss on the raw captured attention, per sample too, and
    more image mass lowers it."""
    from lerobot_policy_gazereg.gaze_targets import gaze_distribution

    from gazereg.integrations.gaze_mass import gaze_mass_kl, gaze_mass_loss

    _, P, _, _ = _classes(kind)
    _, policy = _policies(kind)
    batch = _batch(dataset)
    policy.train()
    torch.manual_seed(4)
    _, plain = policy.forward(dict(batch))
    policy.config.gaze_target_mass = 0.9
    try:
        torch.manual_seed(4)
        _, info = policy.forward(dict(batch))
        torch.manual_seed(4)
        rows, _ = policy.forward(dict(batch), reduction="none")
    finally:
        del policy.config.gaze_target_mass
    cap = policy.gaze_capture
    raw = cap.raw_attention()
    geom, src_hw = policy._geometry()
    gaze, valid = gaze_distribution(batch["gaze.point"], geom, False, policy.config.gaze_sigma, src_hw)
    want, _ = gaze_mass_loss(gaze, raw, 0.9, valid, kind=policy.config.gaze_divergence)
    assert info["loss/gaze_kl"] == pytest.approx(float(want.detach()), rel=1e-5)
    assert info["loss/gaze_kl"] != pytest.approx(plain["loss/gaze_kl"])
    torch.manual_seed(4)
    action_rows, _ = P.forward(policy, dict(batch), reduction="none")  # the plain pi0 loss per sample
    per_sample = gaze_mass_kl(gaze, raw, 0.9, kind=policy.config.gaze_divergence)
    torch.testing.assert_close(
        rows.detach() - action_rows.detach(), per_sample.detach(), rtol=1e-5, atol=1e-6
    )
    (grad,) = torch.autograd.grad(rows.sum(), [cap.state.probe.rows(cap.layers[-1])])  # the last capture
    assert info["gaze/patch_mass"] < 0.9 and float(grad.sum()) < 0  # more image mass lowers the term


def test_geometry_pads_in_the_centre():
    from lerobot_policy_gazereg.modeling_pi0_gaze import pi_geometry

    g = pi_geometry((32, 64), (56, 56), 14)  # a 2:1 frame in a 4x4 grid: content in the middle 2 rows
    assert g.pad == "centre" and g.grid_hw == (4, 4)
    assert g.patch_index(torch.tensor([[0.01, 0.01], [0.99, 0.99]])).tolist() == [4, 11]
    assert pi_geometry((64, 64), (56, 56), 14).resize == "stretch"


# ----- the real lerobot-train ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def train_env(tmp_path_factory) -> dict:
    """Environment for lerobot-train subprocesses: offline, tiny models (a sitecustomize on PYTHONPATH installs
    them at interpreter start) and a tiny tokenizer cached as google/paligemma-3b-pt-224."""
    from lerobot_policy_gazereg.testing import make_offline_paligemma_cache

    root = tmp_path_factory.mktemp("pi_env")
    hub = make_offline_paligemma_cache(root / "hub")
    site = root / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(
        "from lerobot_policy_gazereg.testing import install_tiny_pi_models\ninstall_tiny_pi_models()\n"
    )
    path = os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))
    return {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "HF_HUB_CACHE": str(hub),
            "PYTHONPATH": path, "OMP_NUM_THREADS": "1"}  # fmt: skip


def _lerobot_train(env: dict, out: Path, dataset_root: Path, steps: int, *args: str):
    exe = Path(sys.executable).with_name("lerobot-train")
    cmd = [
        str(exe),
        *args,
        "--dataset.repo_id=local/lerobot_v3_tiny",
        f"--dataset.root={dataset_root}",
        "--dataset.episodes=[0]",
        "--dataset.video_backend=pyav",
        "--batch_size=4",
        f"--steps={steps}",
        "--log_freq=1",
        "--save_freq=2",
        "--num_workers=0",
        "--wandb.enable=false",
        f"--output_dir={out}",
    ]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env)
    log = r.stdout + r.stderr
    assert r.returncode == 0, log[-4000:]
    return log


def _policy_args(kind: str) -> list[str]:
    return [
        f"--policy.type={kind}_gaze",
        "--policy.image_resolution=[56,56]",
        "--policy.chunk_size=5",
        "--policy.n_action_steps=5",
        "--policy.max_state_dim=8",
        "--policy.max_action_dim=8",
        "--policy.tokenizer_max_length=32",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        "--policy.gaze_weight=1.0",
        f"--policy.gaze_camera={CAM}",
        "--policy.gaze_layers=[1]",
        "--policy.scheduler_warmup_steps=0",
    ]


def _kls(log: str) -> list[float]:
    return [float(x) for x in re.findall(r"loss/gaze_kl:([-0-9.naif]+)", log)]


@pytest.fixture(scope="module")
def trained(tmp_path_factory, dataset_root, train_env):
    """kind -> (log, checkpoint dir) of a 2-step lerobot-train run, run once per kind in this module."""
    runs: dict[str, tuple[str, Path]] = {}

    def get(kind: str) -> tuple[str, Path]:
        if kind not in runs:
            run = tmp_path_factory.mktemp(f"train_{kind}") / "run"
            log = _lerobot_train(train_env, run, dataset_root, 2, *_policy_args(kind))
            runs[kind] = (log, run / "checkpoints" / "last" / "pretrained_model")
        return runs[kind]

    return get


@pytest.mark.parametrize("kind", KINDS)
def test_lerobot_train(kind, tiny, trained):
    """`lerobot-train --policy.type={pi0,pi05}_gaze` trains offline, logs the gaze term and saves a checkpoint
    with the gaze options and exactly the base policy's parameters."""
    log, ckpt = trained(kind)
    kls = _kls(log)
    assert len(kls) == 2 and all(math.isfinite(k) and k > 0 for k in kls), log[-3000:]
    assert "loss/action:" in log and "gaze/weight:1.000" in log
    cfg = json.loads((ckpt / "config.json").read_text())
    assert cfg["type"] == f"{kind}_gaze" and cfg["gaze_layers"] == [1] and cfg["gaze_weight"] == 1.0
    from safetensors.torch import load_file

    C, P, _, _ = _classes(kind)
    base_cfg = C(**{k: cfg[k] for k in ("chunk_size", "n_action_steps", "max_state_dim", "max_action_dim")})
    base_cfg.image_resolution = tuple(cfg["image_resolution"])
    base = P(_features(base_cfg))
    state = load_file(ckpt / "model.safetensors")
    assert {k: tuple(v.shape) for k, v in state.items()} == {
        k: tuple(v.shape) for k, v in base.state_dict().items()
    }


def test_lerobot_train_with_gradient_checkpointing(tmp_path, dataset_root, train_env):
    """The real lerobot-train with --policy.gradient_checkpointing=true and the gaze term (refused before)."""
    args = [*_policy_args("pi05"), "--policy.gradient_checkpointing=true"]
    log = _lerobot_train(train_env, tmp_path / "run", dataset_root, 1, *args)
    cfg = json.loads(
        (tmp_path / "run" / "checkpoints" / "last" / "pretrained_model" / "config.json").read_text()
    )
    assert cfg["gradient_checkpointing"] is True
    assert len(_kls(log)) == 1 and all(math.isfinite(k) and k > 0 for k in _kls(log)), log[-3000:]


def test_lerobot_train_resume_and_policy_path(tmp_path, dataset_root, train_env, trained):
    """Resume a pi0_gaze run for one more step, and fine-tune from its checkpoint with --policy.path (the same
    code serves pi05_gaze)."""
    _, ckpt = trained("pi0")
    run = ckpt.parents[2]
    log = _lerobot_train(
        train_env, run, dataset_root, 3, f"--config_path={ckpt / 'train_config.json'}", "--resume=true"
    )
    assert "Resum" in log and len(_kls(log)) == 1, log[-3000:]
    log = _lerobot_train(train_env, tmp_path / "ft", dataset_root, 1, f"--policy.path={ckpt}",
                         "--policy.push_to_hub=false", "--policy.gaze_weight=0.5")  # fmt: skip
    assert "gaze/weight:0.500" in log and len(_kls(log)) == 1, log[-3000:]
