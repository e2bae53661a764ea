"""The transformers gaze term under gradient checkpointing, inside generate() / PI0 sample_actions(), and its
image mass (patch_mass in [0, 1], the mass variant of the loss), on tiny random models."""

from __future__ import annotations

import pytest
import torch

transformers = pytest.importorskip("transformers", reason="the hf extra (transformers) is not installed")

from tiny_models import tiny_batch, tiny_model  # noqa: E402

from gazereg.integrations.gaze_mass import gaze_mass_kl  # noqa: E402
from gazereg.integrations.transformers import GazeRegularizer, detect_family  # noqa: E402
from gazereg.losses import gaze_kl  # noqa: E402
from gazereg.runtime.errors import UsageError  # noqa: E402

VLMS = ["paligemma", "idefics3", "smolvlm", "llava"]


def _gaze(reg: GazeRegularizer, batch: int = 2) -> dict[str, torch.Tensor]:
    out = {}
    for cam, g in reg.cameras.items():
        d = torch.full((batch, g.n_patches), 0.1 / g.n_patches)
        d[:, 2] += 0.9
        out[cam] = d / d.sum(-1, keepdim=True)
    return out


def _term_grads(fam: str, checkpointing: dict | None) -> list[torch.Tensor]:
    """Gradients of the gaze term alone w.r.t. every parameter (zeros where none)."""
    model = tiny_model(fam).train()
    if checkpointing is not None:
        model.gradient_checkpointing_enable(gradient_checkpointing_kwargs=checkpointing or None)
    batch = tiny_batch(model)
    reg = GazeRegularizer(model, layers=[0, 1], weight=1.0)
    with reg:
        model(**batch)
    term, _ = reg.loss(_gaze(reg))
    term.backward()
    return [torch.zeros_like(p) if p.grad is None else p.grad for p in model.parameters()]


@pytest.mark.parametrize("kwargs", [{}, {"use_reentrant": False}], ids=["default", "non_reentrant"])
@pytest.mark.parametrize("fam", VLMS)
def test_gaze_gradient_under_checkpointing_equals_the_plain_one(fam, kwargs):
    ref = _term_grads(fam, None)
    got = _term_grads(fam, kwargs)
    assert sum(float(g.abs().sum()) for g in ref) > 0
    for a, b in zip(ref, got, strict=True):
        torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("fam", VLMS)
def test_reentrant_checkpointing_is_an_error_at_the_first_forward(fam):
    model = tiny_model(fam).train()
    model.gradient_checkpointing_enable(gradient_checkpointing_kwargs={"use_reentrant": True})
    batch = tiny_batch(model)
    reg = GazeRegularizer(model, layers=[0, 1])
    with pytest.raises(UsageError, match="use_reentrant=True.*use_reentrant': False"), reg:
        model(**batch)


def test_pi0_checkpointing_fails_in_transformers_itself_or_keeps_the_gradient():
    model = tiny_model("pi0").train()
    model.gradient_checkpointing_enable()
    try:  # with gradients on, as in training: some versions drop the cache only then
        model(**tiny_batch(model))
    except AttributeError as e:  # transformers' PI0 forward drops its prefix cache under checkpointing
        pytest.skip(f"transformers' PI0 cannot train with gradient checkpointing at all: {e}")
    ref = _term_grads("pi0", None)
    for a, b in zip(ref, _term_grads("pi0", {}), strict=True):
        torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("fam", ["paligemma", "smolvlm", "llava"])
def test_generate_inside_the_context_captures_the_prompt(fam):
    model = tiny_model(fam)
    batch = tiny_batch(model)
    inputs = {k: v for k, v in batch.items() if k not in ("labels", "token_type_ids")}
    reg = GazeRegularizer(model, layers=[0, 1])
    with reg, torch.no_grad():
        model(**inputs)
    want = reg.attention()["image"]
    with reg, torch.no_grad():
        out = model.generate(**inputs, max_new_tokens=3, do_sample=False)
    assert out.shape[1] == inputs["input_ids"].shape[1] + 3
    assert reg.skipped == 2  # the decoding steps hold no image tokens
    torch.testing.assert_close(reg.attention()["image"], want)  # the prompt's forward (prefill)


def test_pi0_sample_actions_inside_the_context_skips_the_capture():
    model = tiny_model("pi0")
    batch = tiny_batch(model)
    reg = GazeRegularizer(model)
    keys = ("state", "input_ids", "pixel_values", "attention_mask", "pixel_attention_mask", "noise")
    with reg, torch.no_grad():
        actions = model.sample_actions(**{k: batch[k] for k in keys}, num_steps=2)
    assert actions.shape == batch["actions"].shape and reg.skipped == 2
    with pytest.raises(RuntimeError, match="no attention captured.*held no image tokens"):
        reg.loss(_gaze(reg))


def test_patch_mass_is_a_mass_when_a_pi0_camera_is_absent():
    model = tiny_model("pi0")
    batch = tiny_batch(model, n_cameras=2)
    tpi = detect_family(model).tokens_per_image(model)
    ids = batch["input_ids"].clone()  # sample 1 has no wrist image: one image block, right-padded
    ids[1, 1 + tpi : -tpi] = ids[1, 1 + 2 * tpi :].clone()
    ids[1, -tpi:] = 0
    batch["input_ids"] = ids
    batch["attention_mask"][1, -tpi:] = 0
    batch["pixel_attention_mask"][1, 1] = False
    reg = GazeRegularizer(model, ["front", "wrist"], layers=[0, 1])
    with reg, torch.no_grad():
        model(**batch)
    mass = reg.patch_mass()
    assert torch.all((mass >= 0) & (mass <= 1 + 1e-6)), mass
    raw = reg.raw_attention()
    assert float(raw["wrist"][1].abs().sum()) == 0  # the absent camera holds no mass
    torch.testing.assert_close(mass, raw["front"].sum(-1) + raw["wrist"].sum(-1))
    _, info = reg.loss(_gaze(reg))
    assert 0 <= info["gaze/patch_mass"] <= 1


def test_mass_variant_decomposes_into_patch_kl_and_mass_kl():
    torch.manual_seed(0)
    gaze = torch.softmax(torch.randn(3, 16), -1)
    raw = torch.softmax(torch.randn(3, 20), -1)[:, :16]  # the attention to 16 of 20 keys
    m = 0.6
    M = raw.sum(-1)
    want = m * gaze_kl(gaze, raw / M[:, None]) + (
        m * torch.log(m / M) + (1 - m) * torch.log((1 - m) / (1 - M))
    )
    torch.testing.assert_close(gaze_mass_kl(gaze, raw, m), want, rtol=1e-5, atol=1e-6)
    with pytest.raises(UsageError, match=r"target mass must be in \(0, 1\]"):
        gaze_mass_kl(gaze, raw, 0.0)


def test_mass_variant_pulls_the_image_mass_up():
    model = tiny_model("smolvlm").train()
    batch = tiny_batch(model)
    reg = GazeRegularizer(model, layers=[0, 1], weight=1.0, target_mass=0.9)
    with reg:
        model(**batch)
    term, info = reg.loss(_gaze(reg))
    mass = reg.raw_attention()["image"].detach().sum(-1).mean()
    (grad,) = torch.autograd.grad(term, [reg.probe.rows(1)], retain_graph=True)
    assert info["gaze/patch_mass"] < 0.9 and float(mass) == pytest.approx(info["gaze/patch_mass"])
    assert float(grad.sum()) < 0  # more mass on the image lowers the term
