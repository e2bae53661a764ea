"""GLC architecture: official state-dict layout, shapes of both presets, the GLC mask."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from gazereg.gaze.glc import GLC, GLCConfig, frame_softmax, prepare_clip
from gazereg.gaze.glc.mvit import GLC_MASK_VALUE, glc_attention_mask


@pytest.fixture(scope="module")
def full_model() -> GLC:
    return GLC(GLCConfig.full()).eval()


@pytest.mark.parametrize("dataset", ["Ego4d", "Egtea"])
def test_state_dict_matches_official(full_model, official_state_dict, dataset):
    ref = official_state_dict[dataset]
    theirs = {name: tuple(shape) for name, shape, _ in ref["state_dict"]}
    ours = {k: tuple(v.shape) for k, v in full_model.state_dict().items()}
    assert len(theirs) == 447
    assert sorted(set(theirs) - set(ours)) == []
    assert sorted(set(ours) - set(theirs)) == []
    assert {k: (ours[k], theirs[k]) for k in ours if ours[k] != theirs[k]} == {}
    dtypes = {name: dtype for name, _, dtype in ref["state_dict"]}
    for k, v in full_model.state_dict().items():
        assert str(v.dtype).removeprefix("torch.") == dtypes[k], k
    assert full_model.num_parameters() == ref["num_parameters"] == 70_181_857


def test_full_config_shapes():
    cfg = GLCConfig.full()
    assert cfg.input_shape == (3, 8, 256, 256)
    assert cfg.token_grid == (4, 64, 64)
    assert cfg.output_shape == (8, 64, 64)
    assert cfg.global_grid == (4, 8, 8)
    specs = cfg.block_specs()
    assert [s["heads"] for s in specs] == [1, 2, 2] + [4] * 11 + [8, 8]
    assert [s["stride_kv"] for s in specs][:4] == [(1, 8, 8), (1, 4, 4), (1, 4, 4), (1, 2, 2)]
    assert specs[14]["stride_kv"] == specs[15]["stride_kv"] == (1, 1, 1)


def test_small_forward_and_heatmaps():
    cfg = GLCConfig.small()
    torch.manual_seed(0)
    model = GLC(cfg).eval()
    assert model.num_parameters() < 5_000_000
    clip = torch.randint(0, 256, (2, 3, 8, 120, 160), dtype=torch.uint8)
    x = prepare_clip(clip, cfg)
    assert x.shape == (2, 3, 8, 96, 96)
    with torch.no_grad():
        logits = model(x)
        maps = model.heatmaps(x)
    assert logits.shape == (2, 1, 8, 24, 24)
    assert maps.shape == (2, 8, 24, 24)
    torch.testing.assert_close(maps.sum((-2, -1)), torch.ones(2, 8))
    torch.testing.assert_close(maps, frame_softmax(logits, 2.0))
    with pytest.raises(ValueError, match="expected input"):
        model(torch.zeros(1, 3, 8, 64, 64))


def test_small_backward_reaches_every_parameter():
    model = GLC(GLCConfig.small()).train()
    model(torch.randn(2, 3, 8, 96, 96)).square().mean().backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert missing == []


def test_config_roundtrip():
    cfg = dataclasses.replace(GLCConfig.small(), drop_path_rate=0.0)
    assert GLCConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ValueError):
        dataclasses.replace(cfg, decoder_heads=(1, 1))


def test_glc_mask_pattern():
    m = glc_attention_mask(4, 1)
    allowed = m == 0
    expected = torch.tensor(
        [[1, 0, 0, 0], [1, 1, 0, 0], [1, 0, 1, 0], [1, 0, 0, 1]],
        dtype=torch.bool,
    )
    assert torch.equal(allowed, expected)
    assert torch.all(m[~allowed] == -GLC_MASK_VALUE)


def test_glc_block_global_token_sees_only_itself():
    torch.manual_seed(0)
    model = GLC(GLCConfig.small()).eval()
    block = model.global_fuse
    thw = (4, 3, 3)
    x = torch.randn(2, 1 + 36, block.dim)
    y = x.clone()
    y[:, 1:] += torch.randn_like(y[:, 1:])
    with torch.no_grad():
        out_x, _ = block(x, thw)
        out_y, _ = block(y, thw)
    torch.testing.assert_close(out_x[:, 0], out_y[:, 0])
    assert not torch.allclose(out_x[:, 1:], out_y[:, 1:])
