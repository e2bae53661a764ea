"""Strict, safe checkpoint loading (official SlowFast files, safetensors) and our save format."""

from __future__ import annotations

import json
import pickle

import pytest
import torch

from gazereg.gaze.glc import GLC, GLCConfig
from gazereg.gaze.glc.checkpoint import (
    CheckpointMismatchError,
    load_glc,
    load_glc_checkpoint,
    read_state_dict,
    save_glc,
)


def _fake_official(official_state_dict) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    sd = {}
    for name, shape, dtype in official_state_dict["Ego4d"]["state_dict"]:
        if dtype == "int64":
            sd[name] = torch.tensor(7, dtype=torch.int64).reshape(shape)
        else:
            sd[name] = torch.randn(shape, generator=g)
    return sd


def test_loads_fake_official_checkpoint(tmp_path, official_state_dict):
    sd = _fake_official(official_state_dict)
    path = tmp_path / "checkpoint_epoch_00015.pyth"
    torch.save(
        {
            "epoch": 15,
            "model_state": {f"module.{k}": v for k, v in sd.items()},
            "optimizer_state": {"state": {}, "param_groups": [{"lr": 1e-4, "params": [0, 1]}]},
            "cfg": "MODEL:\n  MODEL_NAME: GLC_Gaze\n",
        },
        path,
    )
    model = load_glc_checkpoint(GLC(GLCConfig.full()), path)
    own = model.state_dict()
    for k in ("pos_embed_spatial", "global_embed.linear.weight", "decode_block4.attn.upsample_q.weight"):
        assert torch.equal(own[k], sd[k])
    assert int(own["global_embed.bn_0.num_batches_tracked"]) == 7


def test_mismatch_lists_missing_unexpected_misshaped(tmp_path):
    model = GLC(GLCConfig.small())
    sd = dict(model.state_dict())
    del sd["classifier.bias"]
    sd["head.projection.weight"] = torch.zeros(3)
    sd["norm.weight"] = torch.zeros(5)
    path = tmp_path / "broken.pt"
    torch.save({"model_state": sd}, path)
    with pytest.raises(CheckpointMismatchError) as info:
        load_glc_checkpoint(GLC(GLCConfig.small()), path)
    err = info.value
    assert err.missing == ["classifier.bias"]
    assert err.unexpected == ["head.projection.weight"]
    assert err.mismatched == [("norm.weight", (5,), (384,))]
    msg = str(err)
    assert "classifier.bias" in msg and "head.projection.weight" in msg and "norm.weight" in msg


class _Evil:
    def __reduce__(self):
        return (print, ("this must not run",))


def test_refuses_pickled_code(tmp_path):
    path = tmp_path / "evil.pt"
    with open(path, "wb") as f:
        pickle.dump({"model_state": {}, "x": _Evil()}, f, protocol=2)
    with pytest.raises(pickle.UnpicklingError):
        read_state_dict(path)


def test_save_and_load_roundtrip(tmp_path):
    cfg = GLCConfig.small()
    torch.manual_seed(1)
    model = GLC(cfg).eval()
    folder = save_glc(model, cfg, tmp_path / "glc_small")
    assert sorted(p.name for p in folder.iterdir()) == ["config.json", "model.safetensors"]
    assert GLCConfig.from_dict(json.loads((folder / "config.json").read_text())) == cfg
    loaded = load_glc(folder).eval()
    x = torch.randn(1, 3, 8, 96, 96)
    with torch.no_grad():
        torch.testing.assert_close(loaded(x), model(x), rtol=0, atol=0)
    # a safetensors file loads through the generic entry point too, and strictly
    with pytest.raises(CheckpointMismatchError):
        load_glc_checkpoint(GLC(GLCConfig.full()), folder / "model.safetensors")


def test_saved_weights_are_byte_identical_with_an_ordinary_files_mode(tmp_path):
    """Equal weights give equal bytes (the glc source records the file's SHA-256) and the file gets the mode an
    ordinary write gives (safetensors' own writer makes it 0600)."""
    cfg = GLCConfig.small()
    torch.manual_seed(2)
    model = GLC(cfg)
    a = save_glc(model, cfg, tmp_path / "a") / "model.safetensors"
    b = save_glc(model, cfg, tmp_path / "b") / "model.safetensors"
    assert a.read_bytes() == b.read_bytes()
    probe = tmp_path / "probe"
    probe.write_text("x")
    assert a.stat().st_mode & 0o777 == probe.stat().st_mode & 0o777
