"""`lerobot_policy_gazereg.export`: a gaze-trained checkpoint becomes a plain `<base>` one that stock LeRobot
loads (`PreTrainedPolicy.from_pretrained`, no plugin imported) and that acts exactly like the gaze policy."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from conftest import make_config

STOCK_SCRIPT = textwrap.dedent(
    """
    import sys, torch
    from lerobot.configs import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors
    from lerobot.policies.pretrained import PreTrainedPolicy

    out, obs_file, act_file = sys.argv[1:]
    cfg = PreTrainedConfig.from_pretrained(out)
    cls = get_policy_class(cfg.type)
    assert issubclass(cls, PreTrainedPolicy)
    policy = cls.from_pretrained(out)
    pre, post = make_pre_post_processors(cfg, pretrained_path=out)
    obs, noise = torch.load(obs_file)
    with torch.no_grad():
        action = post(policy.select_action(pre(obs), noise=noise))
    torch.save(action, act_file)
    plugin = sorted(m for m in sys.modules if m.startswith("lerobot_policy_gazereg"))
    print(cfg.type, cls.__name__, plugin)
    """
)


@pytest.fixture(scope="module")
def gaze_ckpt(tmp_path_factory, tiny_vlm, dataset) -> Path:
    """A smolvla_gaze checkpoint folder laid out as lerobot-train writes its pretrained_model/."""
    from lerobot.policies import make_policy, make_pre_post_processors

    torch.manual_seed(0)
    cfg = make_config(tiny_vlm, gaze_layers=[1, 3])
    policy = make_policy(cfg, ds_meta=dataset.meta)
    pre, post = make_pre_post_processors(cfg, dataset_stats=dataset.meta.stats)
    out = tmp_path_factory.mktemp("gaze_run") / "pretrained_model"
    policy.save_pretrained(out)
    pre.save_pretrained(out)
    post.save_pretrained(out)
    return out


def test_plain_checkpoint_loads_in_stock_lerobot_and_acts_the_same(gaze_ckpt, dataset, tmp_path):
    from lerobot.policies.factory import make_pre_post_processors
    from lerobot_policy_gazereg.export import export_plain_checkpoint
    from lerobot_policy_gazereg.modeling_smolvla_gaze import SmolVLAGazePolicy

    out = tmp_path / "plain"
    r = export_plain_checkpoint(gaze_ckpt.parent, out)  # the parent of pretrained_model/ works too
    assert (r.gaze_type, r.base_type) == ("smolvla_gaze", "smolvla")
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["type"] == "smolvla" and not [k for k in cfg if k.startswith("gaze")]
    assert set(r.dropped_fields) == {
        f"gaze_{n}" for n in ("weight", "key", "camera", "layers", "sigma", "divergence", "target_mass")
    }
    assert (out / "model.safetensors").read_bytes() == (gaze_ckpt / "model.safetensors").read_bytes()
    assert not [p for p in tmp_path.iterdir() if p.name != "plain"]  # no temporary folder left

    frame = dataset[0]
    obs = {k: v for k, v in frame.items() if k.startswith("observation.")} | {"task": frame["task"]}
    noise = torch.randn(
        1, 5, 32, generator=torch.Generator().manual_seed(3)
    )  # (B, chunk_size, max_action_dim)
    torch.save((obs, noise), tmp_path / "obs.pt")
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-c", STOCK_SCRIPT, str(out), str(tmp_path / "obs.pt"), str(tmp_path / "act.pt")]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.splitlines()[-1].split() == [
        "smolvla",
        "SmolVLAPolicy",
        "[]",
    ]  # stock class, plugin never imported

    gaze = SmolVLAGazePolicy.from_pretrained(gaze_ckpt)
    pre, post = make_pre_post_processors(gaze.config, pretrained_path=str(gaze_ckpt))
    with torch.no_grad():
        want = post(gaze.select_action(pre(dict(obs)), noise=noise))
    got = torch.load(tmp_path / "act.pt")
    assert want.shape == (1, 4) and torch.equal(got, want)


def _fake_gaze_ckpt(path: Path, base_cfg, gaze_type: str) -> Path:
    """A checkpoint folder whose config is `base_cfg` saved as `gaze_type` with gaze fields, plus a processor
    file naming a gaze step (weights are not read by the converter)."""
    path.mkdir(parents=True)
    base_cfg._save_pretrained(path)
    cfg = json.loads((path / "config.json").read_text())
    cfg.update(type=gaze_type, gaze_weight=0.1, gaze_key="gaze.point", gaze_layers=[1])
    (path / "config.json").write_text(json.dumps(cfg))
    (path / "model.safetensors").write_bytes(b"weights")
    steps = [{"registry_name": "to_batch_processor", "config": {}}, {"registry_name": "gaze_keep_processor"}]
    (path / "policy_preprocessor.json").write_text(
        json.dumps({"name": "policy_preprocessor", "steps": steps})
    )
    return path


@pytest.mark.parametrize("base", ["pi0", "pi05"])
def test_pi_gaze_configs_map_to_their_base(tmp_path, base):
    from lerobot.configs import PreTrainedConfig
    from lerobot_policy_gazereg.export import export_plain_checkpoint

    cls = PreTrainedConfig.get_choice_class(base)
    src = _fake_gaze_ckpt(tmp_path / "ckpt", cls(device="cpu"), f"{base}_gaze")
    r = export_plain_checkpoint(src, tmp_path / "plain")
    assert r.base_type == base and set(r.dropped_fields) == {"gaze_weight", "gaze_key", "gaze_layers"}
    assert r.dropped_steps == ("policy_preprocessor.json:gaze_keep_processor",)
    assert type(PreTrainedConfig.from_pretrained(tmp_path / "plain")) is cls
    steps = json.loads((tmp_path / "plain" / "policy_preprocessor.json").read_text())["steps"]
    assert [s["registry_name"] for s in steps] == ["to_batch_processor"]


def test_refusals_are_one_line_and_leave_nothing(tmp_path, capsys):
    from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig
    from lerobot_policy_gazereg.export import export_plain_checkpoint, main

    from gazereg.runtime.errors import UsageError

    plain = tmp_path / "plain"
    plain.mkdir()
    SmolVLAConfig(device="cpu")._save_pretrained(plain)
    assert main([str(plain), str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is not a gaze checkpoint: its type is 'smolvla'" in err
    (tmp_path / "out").mkdir()
    with pytest.raises(UsageError, match="no config.json"):
        export_plain_checkpoint(tmp_path / "out", tmp_path / "x")
    src = _fake_gaze_ckpt(tmp_path / "ckpt", SmolVLAConfig(device="cpu"), "smolvla_gaze")
    with pytest.raises(UsageError, match="already exists and is not an empty folder"):
        export_plain_checkpoint(src, plain)
    (src / "train_config.json").write_text("{not json")
    with pytest.raises(UsageError, match="train_config.json is not readable JSON"):
        export_plain_checkpoint(src, tmp_path / "new")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ckpt", "out", "plain"]  # no half-written folder
