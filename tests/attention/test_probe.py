import math

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from gazereg.attention.probe import AttentionProbe, ProbeSpec, tap
from gazereg.losses import gaze_loss


class TinyAttention(nn.Module):
    """A hand-written attention layer that uses the fused kernel and taps its q and k."""

    def __init__(self, dim: int, heads: int, layer: int):
        super().__init__()
        self.qkv = nn.Linear(dim, 3 * dim)
        self.out = nn.Linear(dim, dim)
        self.heads, self.layer = heads, layer

    def forward(self, x, mask=None):
        B, T, D = x.shape
        q, k, v = self.qkv(x).reshape(B, T, 3, self.heads, D // self.heads).permute(2, 0, 3, 1, 4)
        tap(self.layer, q, k, mask)
        y = F.scaled_dot_product_attention(q, k, v, attn_mask=mask)
        return x + self.out(y.transpose(1, 2).reshape(B, T, D))


class TinyModel(nn.Module):
    def __init__(self, dim=16, heads=2, depth=3):
        super().__init__()
        self.layers = nn.ModuleList(TinyAttention(dim, heads, i) for i in range(depth))
        self.q_proj = [layer.qkv for layer in self.layers]

    def forward(self, x, mask=None):
        for layer in self.layers:
            x = layer(x, mask)
        return x


def _reference_rows(model, x, layer, queries, keys, mask=None):
    """softmax(QK^T / sqrt(d)) computed by hand, layer by layer."""
    h = x
    for i, blk in enumerate(model.layers):
        B, T, D = h.shape
        q, k, _ = blk.qkv(h).reshape(B, T, 3, blk.heads, D // blk.heads).permute(2, 0, 3, 1, 4)
        logits = q @ k.transpose(-1, -2) / math.sqrt(D // blk.heads)
        if mask is not None:
            logits = logits.masked_fill(~mask, float("-inf"))
        if i == layer:
            return torch.softmax(logits, -1)[:, :, queries][..., keys]
        h = blk(h, mask)
    raise AssertionError


def test_probe_returns_exact_softmax_rows_and_output_is_unchanged():
    torch.manual_seed(0)
    model = TinyModel()
    x = torch.randn(2, 10, 16)
    mask = torch.ones(10, 10, dtype=torch.bool).tril()
    spec = ProbeSpec(queries=slice(7, 10), keys=[0, 1, 2, 3], layers=(1, 2))
    ref_out = model(x, mask)
    with AttentionProbe(model, spec) as probe:
        out = model(x, mask)
    assert torch.equal(out, ref_out)  # bit-identical
    for layer in (1, 2):
        torch.testing.assert_close(
            probe.rows(layer), _reference_rows(model, x, layer, slice(7, 10), [0, 1, 2, 3], mask)
        )
    assert probe.layers == [1, 2]
    dist = probe.distribution()
    expected = torch.stack(
        [_reference_rows(model, x, i, slice(7, 10), [0, 1, 2, 3], mask).mean((1, 2)) for i in (1, 2)]
    ).mean(0)
    torch.testing.assert_close(dist, expected / expected.sum(-1, keepdim=True))
    torch.testing.assert_close(dist.sum(-1), torch.ones(2))


def test_probe_is_differentiable_and_inactive_outside_the_context():
    torch.manual_seed(0)
    model = TinyModel()
    x = torch.randn(2, 10, 16)
    spec = ProbeSpec(queries=[9], keys=slice(0, 4), layers=(2,))
    with AttentionProbe(model, spec) as probe:
        model(x)
    gaze = torch.tensor([[1.0, 0, 0, 0], [0, 0, 0, 1.0]])
    loss, _ = gaze_loss(gaze, probe.distribution())
    loss.backward()
    assert model.layers[2].qkv.weight.grad.abs().sum() > 0
    assert model.layers[0].qkv.weight.grad.abs().sum() > 0  # flows through earlier layers' outputs
    probe2 = AttentionProbe(model, spec)
    model(x)  # no active probe: nothing recorded
    with pytest.raises(RuntimeError, match="captured nothing"):
        probe2.distribution()


def test_per_sample_key_positions():
    torch.manual_seed(0)
    model = TinyModel()
    x = torch.randn(2, 10, 16)
    keys = torch.tensor([[0, 1, 2], [5, 6, 7]])
    with AttentionProbe(model, ProbeSpec(queries=[9], keys=keys, layers=(0,))) as probe:
        model(x)
    full = _reference_rows(model, x, 0, [9], slice(None))
    torch.testing.assert_close(probe.rows(0)[0], full[0][..., [0, 1, 2]])
    torch.testing.assert_close(probe.rows(0)[1], full[1][..., [5, 6, 7]])


def test_missing_layer_is_an_error():
    model = TinyModel(depth=2)
    with AttentionProbe(model, ProbeSpec(queries=[0], keys=[1], layers=(5,))) as probe:
        model(torch.randn(1, 4, 16))
    with pytest.raises(RuntimeError, match="captured nothing"):
        probe.distribution()


def test_plain_pytorch_multihead_attention_adapter():
    torch.manual_seed(0)
    layer = nn.TransformerEncoderLayer(d_model=16, nhead=4, dim_feedforward=32, dropout=0.0, batch_first=True)
    model = nn.TransformerEncoder(layer, num_layers=2, enable_nested_tensor=False)
    x = torch.randn(3, 9, 16)
    pad = torch.zeros(3, 9, dtype=torch.bool)
    pad[0, -2:] = True
    ref = model(x, src_key_padding_mask=pad)
    spec = ProbeSpec(queries=[0, 1], keys=slice(2, 7), layers=(1,))
    with AttentionProbe(model, spec) as probe:
        out = model(x, src_key_padding_mask=pad)
    assert torch.equal(out, ref)
    # reference: the attention weights nn.MultiheadAttention itself returns, per head
    h = model.layers[0](x, src_key_padding_mask=pad)
    mha = model.layers[1].self_attn
    _, w = mha(h, h, h, key_padding_mask=pad, need_weights=True, average_attn_weights=False)
    torch.testing.assert_close(probe.rows(1), w[:, :, [0, 1]][..., 2:7], atol=1e-6, rtol=1e-5)


class CheckpointedModel(TinyModel):
    """TinyModel whose layers run under torch.utils.checkpoint (non-reentrant)."""

    def forward(self, x, mask=None):
        for layer in self.layers:
            x = torch.utils.checkpoint.checkpoint(layer, x, mask, use_reentrant=False)
        return x


def _probe_grads(model, x, gaze):
    spec = ProbeSpec(queries=[0, 1], keys=slice(2, 8), layers=(1, 2))
    with AttentionProbe(model, spec, adapter="tap") as probe:
        model(x)
    term, _ = gaze_loss(gaze, probe.distribution())
    term.backward()
    return [torch.zeros_like(p) if p.grad is None else p.grad.clone() for p in model.parameters()]


def test_probe_under_non_reentrant_checkpointing_keeps_the_gradient():
    """The probe's ops keep their own saved tensors: the checkpoint does not count them (no CheckpointError on
    recomputation) and the gaze gradient equals the one without checkpointing."""
    torch.manual_seed(0)
    plain = TinyModel()
    ckpt = CheckpointedModel()
    ckpt.load_state_dict(plain.state_dict())
    x = torch.randn(2, 10, 16)
    gaze = torch.softmax(torch.randn(2, 6), -1)
    for a, b in zip(_probe_grads(plain, x, gaze), _probe_grads(ckpt, x, gaze), strict=True):
        torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-7)
    assert ckpt.layers[1].qkv.weight.grad.abs().sum() > 0


def test_mean_rows_is_the_unnormalised_distribution():
    torch.manual_seed(0)
    model = TinyModel()
    with AttentionProbe(model, ProbeSpec(queries=[0], keys=slice(2, 8)), adapter="tap") as probe:
        model(torch.randn(2, 10, 16))
    raw = probe.mean_rows()
    assert torch.all(raw.sum(-1) < 1)
    torch.testing.assert_close(probe.distribution(), raw / raw.sum(-1, keepdim=True))
    torch.testing.assert_close(probe.patch_mass(), raw.sum(-1).detach())


def test_a_capture_that_never_reaches_a_loss_frees_its_graph():
    """The location control logs the attention detached, so backward never runs through the capture: its saved
    tensors must not keep themselves alive (a pack hook returning the tensor itself made a cycle that leaked
    every training step's graph, ~8 MB a step at the paper preset's size)."""
    import gc
    import weakref

    from gazereg.attention.probe import attention_rows, own_saved_tensors

    q = torch.randn(2, 2, 3, 4, requires_grad=True)
    k = torch.randn(2, 2, 5, 4, requires_grad=True)
    with own_saved_tensors():
        probs = attention_rows(q, k, slice(0, 3), None, None)  # softmax saves its output
    ref = weakref.ref(probs)
    del probs
    gc.collect()
    assert ref() is None
