"""Gaze regularization of a model without an image token id (OpenVLA / Prismatic layout, issue 35 item 5).

The model is a tiny Llama (transformers' LlamaConfig, random weights) behind a tiny vision encoder and projector
of this file; like OpenVLA's PrismaticVLM it inserts the image's patch embeddings after BOS, so input_ids hold no
image token. The keys come from an adapter (`inserted_patch_family`, registered) or from the caller
(`patch_positions=`), and the gaze KL must be the one computed from the eager attention to exactly the positions
[1, 1 + n_patches) of the language model's sequence.
"""

from __future__ import annotations

import pytest
import torch
from torch import nn

transformers = pytest.importorskip("transformers", reason="the hf extra (transformers) is not installed")

from gazereg.integrations.transformers import (  # noqa: E402
    FAMILIES,
    GazeRegularizer,
    camera_geometry,
    detect_family,
    inserted_patch_family,
    register_family,
)
from gazereg.losses import gaze_kl  # noqa: E402
from gazereg.runtime.errors import UsageError  # noqa: E402

VOCAB, IMAGE, PATCH = 120, 32, 8  # a 4x4 grid: 16 patch tokens
N = (IMAGE // PATCH) ** 2


class TinyPrismaticVLM(nn.Module):
    """input_ids (B, T) -> the Llama sees [BOS, N patch embeddings, input_ids[1:]] (T + N tokens), as OpenVLA's
    PrismaticVLM builds its multimodal embeddings; labels and attention_mask are padded the same way."""

    def __init__(self, hidden: int = 32, n_layers: int = 2, attn: str = "sdpa", seed: int = 0):
        super().__init__()
        torch.manual_seed(seed)
        cfg = transformers.LlamaConfig(
            hidden_size=hidden,
            num_hidden_layers=n_layers,
            intermediate_size=2 * hidden,
            num_attention_heads=4,
            num_key_value_heads=2,
            vocab_size=VOCAB,
            max_position_embeddings=128,
        )
        cfg._attn_implementation = attn
        self.language_model = transformers.LlamaForCausalLM(cfg)
        self.vision = nn.Conv2d(3, 24, PATCH, PATCH)  # patch features (B, 24, h, w)
        self.projector = nn.Sequential(nn.Linear(24, hidden), nn.GELU(), nn.Linear(hidden, hidden))

    def forward(
        self, input_ids, attention_mask=None, pixel_values=None, labels=None, output_attentions=False
    ):
        emb = self.language_model.get_input_embeddings()(input_ids)
        B = emb.shape[0]
        patches = self.projector(self.vision(pixel_values).flatten(2).transpose(1, 2))  # (B, N, hidden)
        x = torch.cat([emb[:, :1], patches, emb[:, 1:]], dim=1)
        n = patches.shape[1]
        if attention_mask is not None:
            ones = attention_mask.new_ones(B, n)
            attention_mask = torch.cat([attention_mask[:, :1], ones, attention_mask[:, 1:]], dim=1)
        if labels is not None:
            ignore = labels.new_full((B, n), -100)
            labels = torch.cat([labels[:, :1], ignore, labels[:, 1:]], dim=1)
        return self.language_model(
            inputs_embeds=x, attention_mask=attention_mask, labels=labels, output_attentions=output_attentions
        )


def _family(image_size: int = IMAGE, name: str = "tiny_prismatic"):
    return inserted_patch_family(
        name,
        attention_config=lambda m: m.language_model.config,
        image_size=image_size,
        patch_size=PATCH,
        inserted_at=1,
        class_prefixes=("TinyPrismatic",),
    )


@pytest.fixture
def registered():
    fam = register_family(_family())
    yield fam
    FAMILIES.pop(fam.name, None)


def _batch(B: int = 2, T: int = 9, answer: int = 3, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    ids = torch.randint(2, VOCAB, (B, T), generator=g)
    ids[:, 0] = 1  # BOS
    labels = ids.clone()
    labels[:, : T - answer] = -100  # the last `answer` tokens are the supervised (action) tokens
    return {
        "input_ids": ids,
        "attention_mask": torch.ones_like(ids),
        "pixel_values": torch.randn(B, 3, IMAGE, IMAGE, generator=g),
        "labels": labels,
    }


def _gaze(B: int = 2, peak: int = 5) -> torch.Tensor:
    d = torch.full((B, N), 0.1 / N)
    d[:, peak] += 0.9
    return d / d.sum(-1, keepdim=True)


@pytest.mark.parametrize("impl", ["sdpa", "eager"])
def test_gaze_kl_is_the_attention_to_the_patches_after_bos(registered, impl):
    model = TinyPrismaticVLM(attn=impl).eval()
    assert detect_family(model) is registered
    batch = _batch()
    T = batch["input_ids"].shape[1]
    reg = GazeRegularizer(model, layers=[0, 1], weight=1.0)  # queries: the family's default, "labels"
    assert reg.cameras["image"].grid_hw == (4, 4)
    with reg, torch.no_grad():
        out = model(**batch)
    term, info = reg.loss(_gaze())
    keys, _ = reg.image_positions(batch["input_ids"])
    assert keys[0].tolist() == list(range(1, 1 + N))
    # the reference: the eager attention of the same forward, rows = the positions predicting the labels
    # (input positions T-4..T-2, moved past the N inserted tokens), columns = exactly 1..N
    model.language_model.set_attn_implementation("eager")
    with torch.no_grad():
        ref = model(**batch, output_attentions=True)
    torch.testing.assert_close(ref.logits, out.logits, rtol=0, atol=1e-5)
    rows = torch.arange(T - 4, T - 1) + N
    att = torch.stack([a[:, :, rows][..., 1 : 1 + N] for a in ref.attentions]).mean(dim=(0, 2, 3))  # (B, N)
    for layer in (0, 1):
        want = ref.attentions[layer][:, :, rows][..., 1 : 1 + N]
        torch.testing.assert_close(reg.probe.rows(layer), want, rtol=0, atol=1e-6)
    want_kl = gaze_kl(_gaze(), att / att.sum(-1, keepdim=True)).mean()
    torch.testing.assert_close(term, want_kl, rtol=1e-5, atol=1e-6)
    assert info["gaze/patch_mass"] == pytest.approx(float(att.sum(-1).mean()), abs=1e-6)
    # a shifted window (positions 0..N-1: BOS + N-1 patches) gives another KL: the test can tell them apart
    wrong = torch.stack([a[:, :, rows][..., 0:N] for a in ref.attentions]).mean(dim=(0, 2, 3))
    assert abs(float(gaze_kl(_gaze(), wrong / wrong.sum(-1, keepdim=True)).mean() - want_kl)) > 1e-3


def test_caller_positions_equal_the_adapter_and_last_query_moves_past_the_patches():
    model = TinyPrismaticVLM().eval()
    batch = _batch()
    T = batch["input_ids"].shape[1]
    fam = _family(name="unregistered")
    geom = camera_geometry(model, family=fam)
    by_family = GazeRegularizer(model, {"front": geom}, layers=[1], family=fam, queries="last")
    by_caller = GazeRegularizer(
        model, {"front": geom}, layers=[1], family=fam, queries="last", patch_positions=range(1, 1 + N)
    )
    by_callable = GazeRegularizer(
        model,
        {"front": geom},
        layers=[1],
        family=fam,
        queries="last",
        patch_positions=lambda inputs: torch.arange(1, 1 + N).expand(inputs["input_ids"].shape[0], -1),
    )
    results = []
    for reg in (by_family, by_caller, by_callable):
        assert reg.query_positions(batch, 2, torch.device("cpu")).tolist() == [[T - 1 + N]] * 2
        with reg, torch.no_grad():
            model(**batch)
        results.append(reg.loss({"front": _gaze()})[0])
    torch.testing.assert_close(results[0], results[1], rtol=0, atol=0)
    torch.testing.assert_close(results[0], results[2], rtol=0, atol=0)


def test_gaze_gradient_reaches_the_projector_and_the_term_falls(registered):
    model = TinyPrismaticVLM().train()
    batch = _batch()
    reg = GazeRegularizer(model, layers=[0, 1], weight=1.0)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    kls = []
    for step in range(6):
        with reg:
            out = model(**batch)
        term, info = reg.loss(_gaze())
        opt.zero_grad()
        (out.loss + term).backward()
        if step == 0:
            assert model.projector[0].weight.grad.abs().sum() > 0
        opt.step()
        kls.append(info["loss/gaze_kl"])
    assert kls[-1] < kls[0], kls


def test_a_wrong_patch_count_is_refused_in_one_line():
    model = TinyPrismaticVLM().eval()
    batch = _batch()
    # the adapter says 8x8 = 64 patches, the model inserts 16: the key axis is T + 16, not T + 64
    fam = _family(image_size=64, name="wrong")
    reg = GazeRegularizer(model, layers=[1], family=fam)
    with pytest.raises(UsageError) as e, reg, torch.no_grad():
        model(**batch)
    msg = str(e.value)
    assert "\n" not in msg and "attends over 25 keys" in msg and "make 73" in msg, msg
    # caller's positions: 15 positions for a 4x4 grid, refused when the regularizer is built
    fam = _family(name="right")
    with pytest.raises(UsageError, match=r"^patch_positions: 15 image token positions given, .* need 16$"):
        GazeRegularizer(model, layers=[1], family=fam, patch_positions=list(range(1, 16)))
    # ... and a callable's count at the forward
    reg = GazeRegularizer(model, layers=[1], family=fam, patch_positions=lambda inputs: torch.arange(1, 18))
    with pytest.raises(UsageError, match=r"^patch_positions: 17 image token positions .* need 16$"), reg:
        model(**batch)


def test_family_definition_and_registration_are_checked():
    with pytest.raises(ValueError, match="exactly one of image_token_id"):
        FAMILIES["paligemma"].__class__(
            name="x",
            class_prefixes=(),
            attention_config=lambda m: None,
            vision=lambda m: (32, 8, 1),
            default_resize="stretch",
            default_pad="centre",
            default_queries="last",
        )
    with pytest.raises(ValueError, match="built-in"):
        register_family(_family(name="llava"))
    model = TinyPrismaticVLM()
    with pytest.raises(TypeError, match="no gaze adapter for TinyPrismaticVLM"):
        detect_family(model)
