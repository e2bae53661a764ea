"""The VLA's fast training path (898cbce): explicit-softmax ("math") attention against SDPA, float32
attention probabilities and probe rows under a bf16 autocast, the per-image random shift, the channels-last
stem and the `attention` option's validation."""

import math

import pytest
import torch
import torch.nn.functional as F
from test_vla import _reference_rows, batch, build

from gazereg.attention.probe import AttentionProbe, attention_rows
from gazereg.policies.vla import VLAConfig, layers_vla, modeling_vla
from gazereg.policies.vla.processor_vla import random_shift

BF16 = dict(device_type="cpu", dtype=torch.bfloat16)


def pair(head: str, depth: int = 3):
    """A math-attention and an SDPA policy holding the same weights."""
    math_p = build(head, depth=depth, attention="math")
    sdpa_p = build(head, depth=depth, attention="sdpa")
    torch.nn.init.normal_(sdpa_p.text_pos)  # other weights, so that the load below is what makes them equal
    sdpa_p.load_state_dict(math_p.state_dict())
    assert math_p.blocks[0].attn.impl == "math" and sdpa_p.blocks[0].attn.impl == "sdpa"
    return math_p, sdpa_p


def reference_probs(p, b, layer: int) -> torch.Tensor:
    """Every (B, H, T, T) probability of one layer: softmax(QK^T / sqrt(d) masked), by hand."""
    x = torch.cat([p.prefix_tokens(b), p.action_tokens(b["state"].shape[0])], 1)
    mask = p.attention_mask(b["text_mask"])
    for i, blk in enumerate(p.blocks):
        if i == layer:
            B, T, D = x.shape
            h = blk.attn.heads
            q, k, _ = blk.attn.qkv(blk.norm1(x)).reshape(B, T, 3, h, D // h).permute(2, 0, 3, 1, 4)
            logits = (q @ k.transpose(-1, -2)) / math.sqrt(D // h)
            return torch.softmax(logits.masked_fill(~mask, float("-inf")), -1)
        x, _ = blk(x, mask)
    raise AssertionError(layer)


# ----- 1. math and sdpa compute the same function -----------------------------------------------------------
@pytest.mark.parametrize("head", ["l1", "flow"])
def test_math_and_sdpa_give_the_same_loss_actions_and_gradients(head):
    pm, ps = pair(head)
    b = batch(pm)
    losses = []
    for p in (pm, ps):
        loss, _ = p(b, generator=torch.Generator().manual_seed(3), shift=2)
        loss.backward()
        losses.append(loss)
    assert losses[0].dtype == losses[1].dtype == torch.float32
    torch.testing.assert_close(losses[0], losses[1], rtol=1e-6, atol=1e-6)
    gm, gs = dict(pm.named_parameters()), dict(ps.named_parameters())
    assert gm.keys() == gs.keys()
    for name in gm:
        assert gm[name].grad is not None and gs[name].grad is not None, name
        torch.testing.assert_close(gm[name].grad, gs[name].grad, rtol=1e-5, atol=1e-6, msg=name)
    assert any(gm[n].grad.abs().sum() > 0 for n in gm if "blocks.0.attn.qkv" in n)
    pm.eval(), ps.eval()
    am = pm.predict_action_chunk(b, generator=torch.Generator().manual_seed(4))
    as_ = ps.predict_action_chunk(b, generator=torch.Generator().manual_seed(4))
    assert am.dtype == torch.float32 and am.shape == (3, 4, 2)
    torch.testing.assert_close(am, as_, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("attention", ["math", "sdpa"])
def test_each_option_runs_its_own_kernel_and_the_bias_is_built_once(attention, monkeypatch):
    calls = {"sdpa": 0, "bias_model": 0, "bias_layer": 0}
    sdpa, bias = F.scaled_dot_product_attention, layers_vla.attention_bias

    def counting(key, fn):
        def wrapped(*args, **kwargs):
            calls[key] += 1
            return fn(*args, **kwargs)

        return wrapped

    monkeypatch.setattr(F, "scaled_dot_product_attention", counting("sdpa", sdpa))
    monkeypatch.setattr(modeling_vla, "attention_bias", counting("bias_model", bias))
    monkeypatch.setattr(layers_vla, "attention_bias", counting("bias_layer", bias))
    p = build(depth=3, attention=attention)
    p(batch(p))
    assert calls == {"sdpa": 3 if attention == "sdpa" else 0, "bias_model": 1, "bias_layer": 0}


# ----- 2. the probabilities the math path materialises ------------------------------------------------------
def test_math_attention_probabilities_are_the_masked_softmax():
    p = build(depth=3, attention="math").eval()
    b = batch(p)
    b["text_mask"][0, 2:] = False  # a padded instruction: masked keys inside the prefix as well
    mask = p.attention_mask(b["text_mask"])  # (B, 1, T, T)
    loss_plain, _ = p(b)
    loss, info = p(b, output_attentions=True)
    assert torch.equal(loss, loss_plain)  # asking for the probabilities does not change the forward
    attns = info["attentions"]
    assert len(attns) == 3
    for layer, a in enumerate(attns):
        assert a.dtype == torch.float32 and a.shape == (3, 4, p.n_tokens, p.n_tokens)
        torch.testing.assert_close(a.sum(-1), torch.ones(3, 4, p.n_tokens), rtol=0, atol=1e-5)
        masked = (~mask).expand_as(a)
        assert masked.any() and torch.equal(a[masked], torch.zeros(int(masked.sum())))
        assert (a[~masked] > 0).all()
        ref = reference_probs(p, b, layer)
        torch.testing.assert_close(a, ref, rtol=1e-5, atol=1e-6)
        rows = a[:, :, p.action_positions()][..., p.patch_positions("cam")]
        torch.testing.assert_close(rows, _reference_rows(p, b, layer), rtol=1e-5, atol=1e-6)


def test_attention_bias_is_zero_where_allowed_and_minus_inf_elsewhere():
    p = build()
    mask = p.attention_mask(batch(p)["text_mask"])
    bias = layers_vla.attention_bias(mask)
    assert bias.dtype == torch.float32 and bias.shape == mask.shape
    assert torch.equal(bias[mask], torch.zeros(int(mask.sum())))
    assert (~mask).any() and torch.isneginf(bias[~mask]).all()


def test_output_attentions_stay_float32_rows_summing_to_one_under_bf16_autocast():
    p = build(depth=2).eval()
    b = batch(p)
    mask = p.attention_mask(b["text_mask"])
    with torch.autocast(**BF16):
        _, info = p(b, output_attentions=True)
    for a in info["attentions"]:
        assert a.dtype == torch.float32
        torch.testing.assert_close(a.sum(-1), torch.ones(a.shape[:-1]), rtol=0, atol=2e-2)
        assert torch.equal(a[(~mask).expand_as(a)], torch.zeros(int((~mask).expand_as(a).sum())))


# ----- 3. bf16 autocast: float32 loss, float32 probe --------------------------------------------------------
@pytest.mark.parametrize("attention", ["math", "sdpa"])
def test_bf16_autocast_forward_and_probe_stay_float32_and_close(attention):
    p = build(depth=3, attention=attention)
    b = batch(p)
    spec = p.gaze_probe_spec("cam")
    with AttentionProbe(p, spec, adapter="tap") as ref:
        loss32, _ = p(b, generator=torch.Generator().manual_seed(0))
    with torch.autocast(**BF16), AttentionProbe(p, spec, adapter="tap") as probe:
        loss, _ = p(b, generator=torch.Generator().manual_seed(0))
    assert loss.dtype == torch.float32 and torch.isfinite(loss)
    assert not torch.equal(loss, loss32)  # the autocast really ran the forward in bf16
    torch.testing.assert_close(loss, loss32, rtol=2e-2, atol=2e-2)
    assert probe.layers == ref.layers == [1, 2]
    for layer in probe.layers:
        rows = probe.rows(layer)
        assert rows.dtype == torch.float32 and rows.shape == ref.rows(layer).shape
        torch.testing.assert_close(rows, ref.rows(layer), rtol=2e-2, atol=1e-4)
    d = probe.distribution()
    assert d.dtype == torch.float32 and d.shape == (3, p.config.n_patches)
    torch.testing.assert_close(d.sum(-1), torch.ones(3))
    torch.testing.assert_close(d, ref.distribution(), rtol=2e-2, atol=1e-4)
    (loss + d[:, 0].sum()).backward()  # the bf16 graph back-propagates through the probe
    assert p.blocks[1].attn.qkv.weight.grad.abs().sum() > 0


def test_attention_rows_ignore_an_enclosing_autocast():
    g = torch.Generator().manual_seed(0)
    q, k = torch.randn(2, 4, 9, 16, generator=g), torch.randn(2, 4, 9, 16, generator=g)
    mask = torch.ones(2, 1, 9, 9, dtype=torch.bool).tril()
    outside = attention_rows(q, k, slice(5, 9), mask)
    with torch.autocast(**BF16):
        inside = attention_rows(q, k, slice(5, 9), mask)
        assert torch.matmul(q, k.transpose(-1, -2)).dtype == torch.bfloat16  # the autocast is live
    assert inside.dtype == outside.dtype == torch.float32
    assert torch.equal(inside, outside)


# ----- 4. the per-image random shift ------------------------------------------------------------------------
def reference_shift(images: torch.Tensor, pad: int, g: torch.Generator) -> torch.Tensor:
    B, C, H, W = images.shape
    padded = F.pad(images.contiguous(), (pad, pad, pad, pad), mode="replicate")
    off = torch.randint(0, 2 * pad + 1, (B, 2), generator=g)
    out = torch.empty(B, C, H, W, dtype=images.dtype)
    for i in range(B):
        r, c = int(off[i, 0]), int(off[i, 1])
        out[i] = padded[i, :, r : r + H, c : c + W]
    return out


@pytest.mark.parametrize("channels_last", [False, True])
@pytest.mark.parametrize("pad", [1, 3])
def test_random_shift_matches_the_reference_bit_for_bit(channels_last, pad):
    x = torch.randn(6, 3, 12, 10, generator=torch.Generator().manual_seed(1))
    if channels_last:
        x = x.contiguous(memory_format=torch.channels_last)
        assert not x.is_contiguous()
    ga, gb = torch.Generator().manual_seed(7), torch.Generator().manual_seed(7)
    out = random_shift(x, pad, ga)
    ref = reference_shift(x, pad, gb)
    assert out.shape == x.shape and out.dtype == x.dtype
    assert torch.equal(out, ref)
    assert torch.equal(ga.get_state(), gb.get_state())  # the same draws, nothing more
    assert not torch.equal(out, x)  # some image moved


def test_random_shift_with_pad_zero_returns_the_input():
    x = torch.randn(2, 3, 8, 8)
    g = torch.Generator().manual_seed(0)
    state = g.get_state()
    assert random_shift(x, 0, g) is x
    assert torch.equal(g.get_state(), state)


def test_channels_last_stem_gives_the_tokens_of_the_contiguous_stem():
    p = build()
    x = torch.randn(3, 3, 48, 48, generator=torch.Generator().manual_seed(0))
    ref = p.stem.net(x).flatten(2).transpose(1, 2)  # (B, N, D) in row-major patch order
    for inp in (x, x.contiguous(memory_format=torch.channels_last)):
        tok = p.stem(inp)
        assert tok.shape == (3, p.config.n_patches, p.config.dim)
        torch.testing.assert_close(tok, ref, rtol=1e-5, atol=1e-6)


# ----- 5. validation ----------------------------------------------------------------------------------------
def test_unknown_attention_is_refused_naming_the_option():
    with pytest.raises(ValueError, match=r"unknown attention 'nosuch'.*'math' or 'sdpa'"):
        VLAConfig(attention="nosuch")  # type: ignore[arg-type]
    assert VLAConfig().attention == "math" and VLAConfig(attention="sdpa").attention == "sdpa"
