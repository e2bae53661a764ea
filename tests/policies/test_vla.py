import dataclasses
import math

import numpy as np
import pytest
import torch

from gazereg.attention.probe import AttentionProbe
from gazereg.data.dataset import StoreInfo
from gazereg.losses import gaze_loss
from gazereg.policies import available_policies, load_policy, make_policy, policy_config_class
from gazereg.policies.vla import VLAConfig, VLAPolicy
from gazereg.policies.vla.configuration_vla import large, tiny
from gazereg.policies.vla.processor_vla import Tokenizer, random_shift, to_input_images

INSTR = ["reach the bright square", "press the button"]


def build(head="l1", image=48, depth=3, cameras=("cam",), **kw) -> VLAPolicy:
    torch.manual_seed(0)
    tok = Tokenizer.build(INSTR, max_len=8)
    cfg = VLAConfig(
        cameras=cameras,
        camera_hw=tuple((image, image) for _ in cameras),
        image_hw=(image, image),
        patch_size=12,
        dim=32,
        depth=depth,
        heads=4,
        stem_channels=8,
        max_text_len=8,
        vocab_size=tok.vocab_size,
        state_dim=3,
        action_dim=2,
        chunk=4,
        head=head,
        **kw,
    )
    return VLAPolicy(cfg, tok)


def batch(policy: VLAPolicy, B=3, seed=0):
    g = torch.Generator().manual_seed(seed)
    c = policy.config
    out = {
        f"image.{cam}": torch.randint(0, 256, (B, *hw, 3), generator=g, dtype=torch.uint8)
        for cam, hw in zip(c.cameras, c.camera_hw)
    }
    ids, mask = policy.tokenizer([INSTR[i % 2] for i in range(B)])
    out.update(
        state=torch.randn(B, c.state_dim, generator=g),
        action=torch.randn(B, c.chunk, c.action_dim, generator=g),
        action_pad=torch.zeros(B, c.chunk, dtype=torch.bool),
        text_ids=ids,
        text_mask=mask,
    )
    return out


def test_registry_and_presets():
    assert "vla" in available_policies()
    assert policy_config_class("vla") is VLAConfig and VLAConfig.type == "vla"
    t = dataclasses.replace(
        tiny(), cameras=("corner2",), camera_hw=((96, 96),), state_dim=4, action_dim=4, vocab_size=40
    )
    p = VLAPolicy(t, Tokenizer("words", [f"w{i}" for i in range(38)], t.max_text_len))
    assert 0.5e6 <= p.num_parameters() <= 1.0e6
    assert t.grid_hw == (8, 8) and p.n_tokens == 64 + 12 + 1 + 4
    pc = dataclasses.replace(
        large(), cameras=("corner2",), camera_hw=((224, 224),), state_dim=8, action_dim=7, vocab_size=50
    )
    big = VLAPolicy(pc, Tokenizer("words", [f"w{i}" for i in range(48)], pc.max_text_len))
    assert pc.grid_hw == (16, 16) and 10e6 < big.num_parameters() < 100e6  # GPU-sized
    with pytest.raises(ValueError, match="not resolved"):
        VLAPolicy(tiny(), Tokenizer("bytes"))
    with pytest.raises(ValueError, match="divisible"):
        VLAConfig(image_hw=(50, 50), patch_size=12)


@pytest.mark.parametrize("head", ["l1", "flow"])
def test_shapes_and_loss(head):
    p = build(head, cameras=("a", "b"))
    b = batch(p)
    loss, info = p(b, generator=torch.Generator().manual_seed(0), shift=2)
    assert (
        loss.ndim == 0 and torch.isfinite(loss) and info["loss/action"] == pytest.approx(float(loss.detach()))
    )
    chunk = p.predict_action_chunk(b, generator=torch.Generator().manual_seed(0))
    assert chunk.shape == (3, 4, 2)
    assert p.patch_positions("b") == slice(16, 32) and p.action_positions() == slice(
        p.n_prefix, p.n_prefix + 4
    )
    loss.backward()
    assert all(q.grad is not None for q in p.parameters())  # every parameter takes part


def test_padded_actions_are_excluded_from_the_loss():
    p = build()
    b = batch(p)
    b["action_pad"][:, 2:] = True
    loss1, _ = p(b)
    b["action"][:, 2:] += 100.0
    loss2, _ = p(b)
    assert torch.equal(loss1, loss2)


def test_block_mask_action_query_i_does_not_see_later_queries():
    p = build(depth=2).eval()
    m = p.attention_mask(batch(p)["text_mask"])[0, 0]
    P, K = p.n_prefix, p.config.chunk
    assert not m[:P, P:].any()  # the prefix never sees the actions
    assert torch.equal(m[P:, P:], torch.ones(K, K, dtype=torch.bool).tril())
    b = batch(p)
    ref, _ = p.run_transformer(p.prefix_tokens(b), p.action_tokens(3), p.attention_mask(b["text_mask"]))
    for i in range(K - 1):
        acts = p.action_tokens(3).clone()
        acts[:, i + 1] += 5.0
        out, _ = p.run_transformer(p.prefix_tokens(b), acts, p.attention_mask(b["text_mask"]))
        assert torch.equal(out[:, : i + 1], ref[:, : i + 1])
        assert not torch.allclose(out[:, i + 1], ref[:, i + 1])


def test_padding_text_tokens_are_invisible():
    p = build().eval()
    b = batch(p)
    ref = p.predict_action_chunk(b)
    b["text_ids"] = torch.where(b["text_mask"], b["text_ids"], torch.full_like(b["text_ids"], 3))
    torch.testing.assert_close(p.predict_action_chunk(b), ref, rtol=0, atol=1e-6)


def _reference_rows(p: VLAPolicy, b, layer: int):
    """softmax(QK^T / sqrt(d) masked) of one layer, recomputed by hand from the block inputs."""
    x = torch.cat([p.prefix_tokens(b), p.action_tokens(3)], 1)
    mask = p.attention_mask(b["text_mask"])
    for i, blk in enumerate(p.blocks):
        if i == layer:
            B, T, D = x.shape
            q, k, _ = (
                blk.attn.qkv(blk.norm1(x))
                .reshape(B, T, 3, blk.attn.heads, D // blk.attn.heads)
                .permute(2, 0, 3, 1, 4)
            )
            logits = (q @ k.transpose(-1, -2)) / math.sqrt(D // blk.attn.heads)
            probs = torch.softmax(logits.masked_fill(~mask, float("-inf")), -1)
            return probs[:, :, p.action_positions()][..., p.patch_positions("cam")]
        x, _ = blk(x, mask)
    raise AssertionError


def test_probe_rows_match_reference_softmax_and_forward_is_bit_identical():
    p = build(depth=3).eval()
    b = batch(p)
    spec = p.gaze_probe_spec("cam", layers=(-2, -1))
    assert spec.layers == (1, 2) and p.gaze_probe_spec("cam").layers == (1, 2)
    g = torch.Generator().manual_seed(1)
    loss_ref, _ = p(b, generator=g)
    with AttentionProbe(p, spec, adapter="tap") as probe:
        loss, _ = p(b, generator=torch.Generator().manual_seed(1))
        chunk = p.predict_action_chunk(b)
    assert torch.equal(loss, loss_ref)
    assert torch.equal(chunk, p.predict_action_chunk(b))
    for layer in (1, 2):
        torch.testing.assert_close(probe.rows(layer), _reference_rows(p, b, layer))
    assert probe.layers == [1, 2]
    d = probe.distribution()
    assert d.shape == (3, p.config.n_patches)
    torch.testing.assert_close(d.sum(-1), torch.ones(3))
    # the probe consumed no RNG
    torch.manual_seed(5)
    with AttentionProbe(p, spec, adapter="tap"):
        p(b)
    a = torch.rand(1)
    torch.manual_seed(5)
    p(b)
    assert torch.equal(a, torch.rand(1))


def test_gaze_gradient_reaches_the_model_up_to_the_probed_layer():
    p = build(depth=3)
    b = batch(p)
    with AttentionProbe(p, p.gaze_probe_spec("cam", layers=(1,)), adapter="tap") as probe:
        p(b)
    gaze = torch.zeros(3, p.config.n_patches)
    gaze[:, 5] = 1.0
    kl, _ = gaze_loss(gaze, probe.distribution())
    kl.backward()
    assert p.stem.net[0].weight.grad.abs().sum() > 0
    assert p.image_pos.grad.abs().sum() > 0
    assert p.blocks[1].attn.qkv.weight.grad.abs().sum() > 0
    assert p.blocks[2].attn.qkv.weight.grad is None  # after the probed layer: no gaze gradient
    assert p.action_out.weight.grad is None


def test_eager_attention_matches_sdpa():
    p = build().eval()
    b = batch(p)
    l1, _ = p(b)
    l2, info = p(b, output_attentions=True)
    torch.testing.assert_close(l1, l2)
    assert len(info["attentions"]) == 3 and info["attentions"][0].shape == (3, 4, p.n_tokens, p.n_tokens)


@pytest.mark.parametrize("head", ["l1", "flow"])
def test_save_load_round_trip_gives_identical_actions(tmp_path, head):
    p = build(head)
    p.normalizer.set_stats([0.1, 0.2, 0.3], [1.0, 2.0, 0.0], [0.5, -0.5], [2.0, 3.0])
    p.save_pretrained(tmp_path / "ckpt")
    assert sorted(f.name for f in (tmp_path / "ckpt").iterdir()) == [
        "config.json",
        "model.safetensors",
        "tokenizer.json",
    ]
    q = load_policy(tmp_path / "ckpt")
    assert isinstance(q, VLAPolicy) and q.config == p.config and q.num_parameters() == p.num_parameters()
    assert q.normalizer.state_std[2] == pytest.approx(p.config.norm_eps)
    obs = {
        "state": np.array([0.1, 0.2, 0.3], np.float32),
        "cam": np.random.default_rng(0).integers(0, 256, (48, 48, 3), dtype=np.uint8),
    }
    p.eval()
    p.reset()
    q.reset()
    for _ in range(3):
        a = p.select_action(obs, INSTR[0], generator=torch.Generator().manual_seed(0))
        b = q.select_action(obs, INSTR[0], generator=torch.Generator().manual_seed(0))
        assert a.shape == (2,) and a.dtype == np.float32
        np.testing.assert_array_equal(a, b)


def test_receding_horizon_and_temporal_ensembling(monkeypatch):
    p = build(n_action_steps=2).eval()
    calls = []
    chunks = iter(torch.arange(40, dtype=torch.float32).reshape(5, 1, 4, 2))

    def fake_predict(batch, generator=None):
        calls.append(1)
        return next(chunks)

    monkeypatch.setattr(p, "predict_action_chunk", fake_predict)
    obs = {"state": np.zeros(3, np.float32), "image.cam": np.zeros((48, 48, 3), np.uint8)}
    acts = [p.select_action(obs, "reach") for _ in range(4)]
    assert len(calls) == 2  # a new chunk every n_action_steps
    np.testing.assert_array_equal(np.stack(acts), [[0, 1], [2, 3], [8, 9], [10, 11]])
    p.reset()
    # temporal ensembling: mean of every chunk's prediction for now, weights exp(-0 * i) = 1
    q = build(temporal_ensemble=0.0).eval()
    chunks2 = iter(torch.arange(24, dtype=torch.float32).reshape(3, 1, 4, 2))
    monkeypatch.setattr(q, "predict_action_chunk", lambda batch, generator=None: next(chunks2))
    a0 = q.select_action(obs, "reach")
    a1 = q.select_action(obs, "reach")
    a2 = q.select_action(obs, "reach")
    np.testing.assert_allclose(a0, [0, 1])
    np.testing.assert_allclose(a1, ([2, 3] + np.array([8, 9])) / 2)
    np.testing.assert_allclose(a2, ([4, 5] + np.array([10, 11]) + np.array([16, 17])) / 3)


def test_batched_observations():
    p = build().eval()
    obs = {"state": np.zeros((2, 3), np.float32), "images": {"cam": np.zeros((2, 48, 48, 3), np.uint8)}}
    assert p.select_action(obs, ["reach", "press"]).shape == (2, 2)
    with pytest.raises(KeyError, match="camera"):
        p.make_batch({"state": np.zeros(3)}, "reach")


def test_tokenizer():
    tok = Tokenizer.build(["Reach the goal", "press the button"], max_len=4)
    ids, mask = tok(["reach the goal!", "push"])
    assert ids.shape == (2, 4) and mask.tolist() == [[True, True, True, False], [True, False, False, False]]
    assert ids[1, 0] == 1 and tok.unknown_words("push") == ["push"]
    assert Tokenizer.from_dict(tok.to_dict()).vocab == tok.vocab
    b = Tokenizer("bytes", max_len=8)
    assert b.vocab_size == 258 and b("ab")[0][0, :2].tolist() == [ord("a") + 2, ord("b") + 2]


@pytest.mark.parametrize("orientation", ["none", "rot180", "hflip"])
def test_image_pipeline_agrees_with_the_patch_geometry(orientation):
    """A bright pixel block in the stored frame lands in the token the geometry maps its centre to."""
    p = build(image=48, orientation=orientation)
    p2 = VLAPolicy(dataclasses.replace(p.config, camera_hw=((96, 96),)), p.tokenizer)
    geo = p2.geometry("cam")  # stored at 96 px; the policy stretches to 48
    frame = torch.zeros(1, 96, 96, 3, dtype=torch.uint8)
    frame[0, 10:18, 60:68] = 255  # centre (u, v) = (64/96, 14/96)
    img = to_input_images(frame, (48, 48), orientation)
    gh, gw = geo.grid_hw
    cell = img[0].mean(0).reshape(gh, 12, gw, 12).mean((1, 3)).flatten()
    assert int(cell.argmax()) == int(geo.patch_index(torch.tensor([64 / 96, 14 / 96])))


def test_random_shift_is_seeded_and_bounded():
    x = torch.arange(2 * 3 * 8 * 8, dtype=torch.float32).reshape(2, 3, 8, 8)
    a = random_shift(x, 2, torch.Generator().manual_seed(0))
    b = random_shift(x, 2, torch.Generator().manual_seed(0))
    assert torch.equal(a, b) and a.shape == x.shape
    assert torch.equal(random_shift(x, 0, torch.Generator()), x)


def test_make_policy_resolves_the_config_from_the_data():
    data = StoreInfo(
        cameras=("a", "b"),
        camera_hw=((64, 48), (32, 32)),
        state_dim=5,
        action_dim=3,
        instructions=tuple(INSTR),
        tasks=("t",),
        n_frames=10,
    )
    torch.manual_seed(0)
    p = make_policy(VLAConfig(image_hw=(48, 48), dim=32, depth=2, stem_channels=8), data)
    c = p.config
    assert isinstance(p, VLAPolicy) and c.resolved and p.name == "vla"
    assert (c.cameras, c.camera_hw, c.state_dim, c.action_dim) == (data.cameras, data.camera_hw, 5, 3)
    assert c.vocab_size == p.tokenizer.vocab_size == len(Tokenizer.build(INSTR).vocab)
    torch.manual_seed(0)
    q = VLAPolicy(c, Tokenizer.build(INSTR, max_len=c.max_text_len))  # the same seed, the same weights
    assert all(torch.equal(a, b) for a, b in zip(p.state_dict().values(), q.state_dict().values()))
    assert VLAConfig.from_dict({"type": "vla", **c.to_dict()}) == c
