"""The SmolVLA gaze capture under gradient checkpointing (SmolVLA 0.6.1 has no checkpointing option, so its
decoder layers are wrapped in torch.utils.checkpoint here, as a user or a fork would), its image mass and the
mass variant of the loss (`gaze_target_mass`)."""

from __future__ import annotations

import functools

import pytest
import torch

from gazereg.runtime.errors import UsageError


def _noise_time(policy, batch):
    g = torch.Generator().manual_seed(1)
    B = batch["action"].shape[0]
    noise = torch.randn(B, policy.config.chunk_size, policy.config.max_action_dim, generator=g)
    return noise, torch.full((B,), 0.5)


def _checkpoint_layers(policy, reentrant: bool) -> None:
    """Run every decoder layer of SmolVLA's VLM-with-expert under torch.utils.checkpoint."""
    vwe = policy.model.vlm_with_expert
    for name in ("forward_attn_layer", "forward_cross_attn_layer"):
        raw = getattr(type(vwe), name).__get__(vwe)

        def run(*args, _raw=raw, **kwargs):
            fn = functools.partial(_raw, **kwargs)
            return torch.utils.checkpoint.checkpoint(fn, *args, use_reentrant=reentrant)

        setattr(vwe, name, run)


def _gaze_grads(policy, batch, reentrant: bool | None) -> list[torch.Tensor]:
    """Gradients of the weighted gaze term alone (total loss minus the action loss's own graph)."""
    policy.train()
    policy.zero_grad()
    if reentrant is not None:
        _checkpoint_layers(policy, reentrant)
    noise, time = _noise_time(policy, batch)
    try:
        total, info = policy.forward(dict(batch), noise=noise, time=time)
    finally:
        for name in ("forward_attn_layer", "forward_cross_attn_layer"):
            policy.model.vlm_with_expert.__dict__.pop(name, None)
    params = [p for p in policy.parameters() if p.requires_grad]
    kl = policy.gaze_capture.attention()  # the term's own graph: recompute the KL from the captured rows
    assert torch.isfinite(total) and info["loss/gaze_kl"] > 0
    target = torch.full_like(kl, 0.1 / kl.shape[-1])
    target[:, 0] += 0.9
    term = (target * (target.log() - kl.clamp_min(1e-8).log())).sum(-1).mean()
    grads = torch.autograd.grad(term, params, allow_unused=True)
    return [torch.zeros_like(p) if g is None else g for p, g in zip(params, grads, strict=True)]


def test_gaze_gradient_under_non_reentrant_checkpointing_equals_the_plain_one(policy_and_batch):
    policy, batch, _ = policy_and_batch
    ref = _gaze_grads(policy, batch, None)
    got = _gaze_grads(policy, batch, False)
    assert sum(float(g.abs().sum()) for g in ref) > 0
    for a, b in zip(ref, got, strict=True):
        torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-7)


def test_reentrant_checkpointing_is_an_error_at_the_first_forward(policy_and_batch):
    policy, batch, _ = policy_and_batch
    with pytest.raises(UsageError, match="use_reentrant=True"):
        _gaze_grads(policy, batch, True)
    assert not policy.model.vlm_with_expert.__dict__.keys() & {"eager_attention_forward", "embed_image"}


def test_patch_mass_is_the_raw_attention_mass(policy_and_batch):
    policy, batch, _ = policy_and_batch
    policy.train()
    noise, time = _noise_time(policy, batch)
    _, info = policy.forward(dict(batch), noise=noise, time=time)
    raw = policy.gaze_capture.raw_attention()
    assert 0 < info["gaze/patch_mass"] <= 1
    assert info["gaze/patch_mass"] == pytest.approx(float(raw.detach().sum(-1).mean()), rel=1e-5)
    torch.testing.assert_close(
        policy.gaze_capture.attention(), raw / raw.sum(-1, keepdim=True), rtol=1e-5, atol=1e-7
    )


def test_target_mass_variant_changes_the_term_and_pulls_the_mass_up(policy_and_batch):
    from lerobot_policy_gazereg.gaze_targets import gaze_distribution

    from gazereg.integrations.gaze_mass import gaze_mass_loss

    policy, batch, _ = policy_and_batch
    policy.train()
    noise, time = _noise_time(policy, batch)
    _, plain = policy.forward(dict(batch), noise=noise, time=time)
    policy.config.gaze_target_mass = 0.9  # the config field (pending in configuration_smolvla_gaze.py)
    try:
        total, info = policy.forward(dict(batch), noise=noise, time=time)
    finally:
        del policy.config.gaze_target_mass
    raw = policy.gaze_capture.raw_attention()
    geom, flip, src_hw = policy._geometry()
    gaze, valid = gaze_distribution(batch["gaze.point"], geom, flip, policy.config.gaze_sigma, src_hw)
    want, _ = gaze_mass_loss(gaze, raw, 0.9, valid, kind=policy.config.gaze_divergence)
    assert info["loss/gaze_kl"] == pytest.approx(float(want.detach()), rel=1e-5)
    assert info["loss/gaze_kl"] != pytest.approx(plain["loss/gaze_kl"])
    cap = policy.gaze_capture
    (grad,) = torch.autograd.grad(total, [cap.state.probe.rows(cap.layers[-1])])
    assert info["gaze/patch_mass"] < 0.9 and float(grad.sum()) < 0  # more image mass lowers the term
