import math

import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from gazereg.losses import WeightSchedule, gaze_kl, gaze_loss


def _dists(seed, n=16, b=4, sparse=False):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(b, n, generator=g)
    if sparse:
        x = x * (torch.rand(b, n, generator=g) > 0.6)
        x[:, 0] += 0.1
    return x / x.sum(-1, keepdim=True)


@given(seed=st.integers(0, 10_000), kind=st.sampled_from(["forward", "reverse", "js"]), sparse=st.booleans())
def test_divergence_is_zero_on_equal_and_non_negative(seed, kind, sparse):
    p, q = _dists(seed, sparse=sparse), _dists(seed + 1, sparse=sparse)
    assert torch.allclose(gaze_kl(p, p, kind), torch.zeros(4), atol=1e-6)
    d = gaze_kl(p, q, kind)
    assert (d >= 0).all() and torch.isfinite(d).all()


def test_forward_kl_matches_definition():
    p, q = _dists(0), _dists(1)
    ref = (p * (p.log() - q.log())).sum(-1)
    torch.testing.assert_close(gaze_kl(p, q), ref)
    torch.testing.assert_close(gaze_kl(p, q, "reverse"), (q * (q.log() - p.log())).sum(-1))
    assert gaze_kl(p, q, "js").max() <= math.log(2) + 1e-6


def test_gradients_reach_attention_not_gaze():
    gaze = _dists(0).requires_grad_(True)
    logits = torch.randn(4, 16, requires_grad=True)
    loss, _ = gaze_loss(gaze, torch.softmax(logits, -1))
    loss.backward()
    assert logits.grad is not None and logits.grad.abs().sum() > 0
    assert gaze.grad is None


def test_zeros_in_either_input_stay_finite():
    gaze = torch.zeros(2, 8)
    gaze[:, 0] = 1
    attn = torch.zeros(2, 8, requires_grad=True)
    a = attn + torch.tensor([0.0, 1, 0, 0, 0, 0, 0, 0])
    loss, _ = gaze_loss(gaze, a)
    loss.backward()
    assert torch.isfinite(loss) and torch.isfinite(attn.grad).all()


def test_invalid_samples_are_excluded_and_all_invalid_gives_zero():
    gaze, attn = _dists(0), _dists(1)
    valid = torch.tensor([True, False, True, False])
    loss, info = gaze_loss(gaze, attn, valid)
    torch.testing.assert_close(loss, gaze_kl(gaze, attn)[valid].mean())
    assert info["gaze/valid_frac"] == 0.5
    logits = torch.randn(4, 16, requires_grad=True)
    loss, info = gaze_loss(gaze, torch.softmax(logits, -1), torch.zeros(4, dtype=torch.bool))
    assert loss.item() == 0.0 and info["gaze/no_valid"] == 1.0
    loss.backward()  # still part of the graph
    assert logits.grad.abs().sum() == 0


def test_bad_inputs_are_errors_not_nan():
    with pytest.raises(ValueError, match="NaN"):
        gaze_loss(torch.full((2, 4), float("nan")), _dists(0, n=4, b=2))
    with pytest.raises(ValueError, match="same shape"):
        gaze_loss(_dists(0, n=4), _dists(0, n=5))
    with pytest.raises(ValueError, match="divergence"):
        gaze_kl(_dists(0), _dists(1), "hellinger")


def test_weight_schedules():
    c = WeightSchedule(0.5)
    assert c(0) == c(10_000) == 0.5
    w = WeightSchedule(1.0, "linear_warmup", warmup_steps=10)
    assert w(0) == pytest.approx(0.1) and w(9) == 1.0 and w(500) == 1.0
    cos = WeightSchedule(1.0, "cosine", total_steps=100)
    assert cos(0) == pytest.approx(1.0) and cos(50) == pytest.approx(0.5) and cos(100) == pytest.approx(0.0)
    assert cos(1000) == pytest.approx(0.0)
    with pytest.raises(ValueError):
        WeightSchedule(-1.0)


def test_half_precision_attention_gives_a_finite_loss_and_finite_gradients():
    # fp16 rounds the 1e-8 floor to 0: computed in fp16 the KL of a near-zero attention cell is inf
    gaze = _dists(0)
    logits = torch.full((4, 16), -30.0)
    logits[:, 0] = 30.0
    logits = logits.half().requires_grad_(True)
    loss, _ = gaze_loss(gaze, torch.softmax(logits.float(), -1).half())
    assert loss.dtype == torch.float32 and torch.isfinite(loss)
    loss.backward()
    assert torch.isfinite(logits.grad).all()
    ref, _ = gaze_loss(gaze, torch.softmax(logits.detach().float(), -1).half().float())
    torch.testing.assert_close(loss.detach(), ref)


def test_bfloat16_attention_matches_float32_of_the_same_values():
    gaze, attn = _dists(0), _dists(1).bfloat16()
    loss, _ = gaze_loss(gaze, attn)
    ref, _ = gaze_loss(gaze, attn.float())
    assert loss.dtype == torch.float32
    torch.testing.assert_close(loss, ref)


@pytest.mark.parametrize("eps", [0.0, -1e-8, float("nan"), float("inf")])
def test_a_non_positive_or_non_finite_eps_is_refused(eps):
    with pytest.raises(ValueError, match="eps"):
        gaze_loss(_dists(0), _dists(1), eps=eps)


@pytest.mark.parametrize("weight", [float("nan"), float("inf"), -0.1])
def test_a_non_finite_or_negative_weight_is_refused(weight):
    with pytest.raises(ValueError, match="weight"):
        WeightSchedule(weight)


def test_grids_with_the_same_patch_count_but_another_shape_are_refused():
    gaze, attn = _dists(0, n=64), _dists(1, n=64)
    gaze_loss(gaze, attn, gaze_grid=(8, 8), attention_grid=(8, 8))
    with pytest.raises(ValueError, match=r"gaze grid \(8, 8\) and attention grid \(4, 16\) differ"):
        gaze_loss(gaze, attn, gaze_grid=(8, 8), attention_grid=(4, 16))
    with pytest.raises(ValueError, match="does not hold"):
        gaze_loss(gaze, attn, gaze_grid=(4, 8))
