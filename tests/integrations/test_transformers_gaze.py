"""Gaze regularization of transformers' PI0, PaliGemma, Idefics3, SmolVLM and Llava (tiny random configs).

For every family: the gaze term's gradient reaches the model, the capture leaves the model's outputs
bit-identical, the captured rows equal the eager attention returned with output_attentions=True, and a
camera/grid mapping that does not fit the prompt's image tokens is an error naming both sides.
"""

from __future__ import annotations

import pytest
import torch

transformers = pytest.importorskip("transformers", reason="the hf extra (transformers) is not installed")

from tiny_models import tiny_batch, tiny_model  # noqa: E402

from gazereg.integrations.transformers import (  # noqa: E402
    GazeRegularizer,
    camera_geometry,
    detect_family,
    gaze_attention_name,
)
from gazereg.patches import PatchGeometry  # noqa: E402

CLASSES = {
    "pi0": "PI0ForConditionalGeneration",
    "paligemma": "PaliGemmaForConditionalGeneration",
    "idefics3": "Idefics3ForConditionalGeneration",
    "smolvlm": "SmolVLMForConditionalGeneration",
    "llava": "LlavaForConditionalGeneration",
}


def _family(name: str) -> str:
    if not hasattr(transformers, CLASSES[name]):
        pytest.skip(f"transformers {transformers.__version__} has no {CLASSES[name]}")
    return name


FAMILIES = [pytest.param(f, id=f) for f in CLASSES]


def _model(fam: str, impl: str = "sdpa", **kw):
    return tiny_model(_family(fam), attn_implementation=impl, **kw)


def _uniform_gaze(reg: GazeRegularizer, batch: int, peak: int = 0) -> dict[str, torch.Tensor]:
    out = {}
    for cam, g in reg.cameras.items():
        d = torch.full((batch, g.n_patches), 0.1 / g.n_patches)
        d[:, peak] += 0.9
        out[cam] = d / d.sum(-1, keepdim=True)
    return out


def _query_rows(fam: str, model, batch) -> torch.Tensor:
    if fam == "pi0":
        return torch.arange(1, model.config.chunk_size + 1)
    return torch.tensor([batch["input_ids"].shape[1] - 1])  # "last": no padding in tiny_batch


@pytest.mark.parametrize("fam", FAMILIES)
@pytest.mark.parametrize("impl", ["sdpa", "eager"])
def test_outputs_are_bit_identical_and_config_restored(fam, impl):
    model = _model(fam, impl)
    batch = tiny_batch(model, n_cameras=2)
    with torch.no_grad():
        ref = model(**batch)
    reg = GazeRegularizer(model, ["front", "wrist"], layers=[0, 1])
    before = reg.config._attn_implementation
    with reg, torch.no_grad():
        out = model(**batch)
        assert reg.config._attn_implementation == before  # switched only during the forward
    assert reg.config._attn_implementation == before
    # Same base function, same arguments, same mask: the capture only reads q and k.
    assert torch.equal(out.logits, ref.logits)
    assert torch.equal(out.loss, ref.loss)
    att = reg.attention()
    assert set(att) == {"front", "wrist"}
    for a in att.values():
        torch.testing.assert_close(a.sum(-1), torch.ones(2))


@pytest.mark.parametrize("fam", FAMILIES)
@pytest.mark.parametrize("impl", ["sdpa", "eager"])
def test_captured_rows_equal_eager_output_attentions(fam, impl):
    model = _model(fam, impl)
    batch = tiny_batch(model, n_cameras=2)
    reg = GazeRegularizer(model, ["front", "wrist"], layers=[0, 1])
    with reg, torch.no_grad():
        model(**batch)
    keys, _ = reg.image_positions(batch["input_ids"])
    model.set_attn_implementation("eager")
    with torch.no_grad():
        ref = model(**batch, output_attentions=True)
    q = _query_rows(fam, model, batch)
    for layer in (0, 1):
        full = ref.attentions[layer]  # (B, H, Tq, Tk), the eager softmax
        want = torch.stack([full[b][:, q][..., keys[b]] for b in range(full.shape[0])])
        torch.testing.assert_close(reg.probe.rows(layer), want, rtol=0, atol=1e-6)
    # and the regularizer's per-camera distribution is that mean, renormalised per camera
    mean = torch.stack(
        [torch.stack([full[b][:, q][..., keys[b]] for b in range(2)]) for full in ref.attentions[:2]]
    )
    mean = mean.mean(dim=(0, 2, 3))
    n = reg.cameras["front"].n_patches
    front = mean[:, :n] / mean[:, :n].sum(-1, keepdim=True)
    torch.testing.assert_close(reg.attention()["front"], front, rtol=0, atol=1e-6)


@pytest.mark.parametrize("fam", FAMILIES)
def test_gaze_gradient_reaches_the_model(fam):
    model = _model(fam).train()
    batch = tiny_batch(model, n_cameras=1)
    reg = GazeRegularizer(model, layers=[1], weight=1.0)
    with reg:
        model(**batch)
    term, info = reg.loss(_uniform_gaze(reg, 2))
    assert torch.isfinite(term) and term > 0 and info["gaze/weight"] == 1.0
    term.backward()
    layer = reg.modules[1]
    assert layer.q_proj.weight.grad is not None and layer.q_proj.weight.grad.abs().sum() > 0
    # ... and through the image tokens' keys into the vision tower
    vision = [p for n, p in model.named_parameters() if "vision" in n and p.grad is not None]
    assert vision and sum(float(p.grad.abs().sum()) for p in vision) > 0
    # nothing after the regularized layer gets a gaze gradient (layer 1 is the last one)
    assert layer.o_proj.weight.grad is None or layer.o_proj.weight.grad.abs().sum() == 0


@pytest.mark.parametrize("fam", FAMILIES)
def test_gaze_term_falls_when_trained(fam):
    model = _model(fam).train()
    batch = tiny_batch(model, n_cameras=1)
    reg = GazeRegularizer(model, layers=[0, 1], weight=1.0)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    kls = []
    for _ in range(6):
        with reg:
            out = model(**batch)
        term, info = reg.loss(_uniform_gaze(reg, 2, peak=3))
        opt.zero_grad()
        (out.loss + term).backward()
        opt.step()
        kls.append(info["loss/gaze_kl"])
    assert kls[-1] < kls[0], kls


@pytest.mark.parametrize("fam", FAMILIES)
def test_wrong_camera_mapping_is_an_error_naming_both(fam):
    model = _model(fam)
    grid = detect_family(model).grid_hw(model)
    # 1. a geometry whose patch grid is not the model's
    bad = PatchGeometry(input_hw=(64, 64), patch_size=8)
    with pytest.raises(ValueError, match=r"\(8, 8\).*" + str(grid).replace("(", r"\(").replace(")", r"\)")):
        GazeRegularizer(model, {"front": bad})
    # 2. two cameras declared, one image in the prompt
    batch = tiny_batch(model, n_cameras=1)
    reg = GazeRegularizer(model, ["front", "wrist"])
    tpi = detect_family(model).tokens_per_image(model)
    msg = rf"holds {tpi} image tokens .* needs {2 * tpi}: front .* wrist"
    if fam == "pi0":  # PI0 reads the camera slots from pixel_attention_mask: a shape error naming both
        msg = r"pixel_attention_mask has shape \(2, 1\), but 2 camera\(s\) \['front', 'wrist'\]"
    with pytest.raises(ValueError, match=msg), reg:
        model(**batch)
    assert reg.config._attn_implementation != gaze_attention_name("sdpa")  # restored after the error


def test_layers_out_of_range_and_missing_input_ids_are_errors():
    model = _model("paligemma")
    with pytest.raises(ValueError, match=r"has 2 regularizable layers \(0..1\)"):
        GazeRegularizer(model, layers=[2])
    reg = GazeRegularizer(model)
    batch = tiny_batch(model)
    embeds = model.get_input_embeddings()(batch.pop("input_ids").clamp_max(100))
    with pytest.raises(ValueError, match="needs `input_ids`"), reg:
        model(inputs_embeds=embeds, **batch)
    with pytest.raises(RuntimeError, match="no attention captured"):
        GazeRegularizer(model).loss(torch.full((2, 16), 1 / 16))


def test_pi0_absent_camera_is_masked_out_of_the_loss():
    model = _model("pi0")
    batch = tiny_batch(model, n_cameras=2)
    tpi = detect_family(model).tokens_per_image(model)
    # sample 1 has no wrist image: its prompt holds one image block, right-padded to the same length
    ids = batch["input_ids"].clone()
    ids[1, 1 + tpi : -tpi] = ids[1, 1 + 2 * tpi :].clone()
    ids[1, -tpi:] = 0
    batch["input_ids"] = ids
    batch["attention_mask"][1, -tpi:] = 0
    batch["pixel_attention_mask"][1, 1] = False
    reg = GazeRegularizer(model, ["front", "wrist"], layers=[0])
    with reg:
        model(**batch)
    assert reg.present.tolist() == [[True, True], [True, False]]
    keys, _ = reg.image_positions(ids, batch["pixel_attention_mask"])
    assert keys[1, :tpi].tolist() == list(range(1, 1 + tpi))
    gaze = _uniform_gaze(reg, 2)
    _, info = reg.loss(gaze)
    assert info["gaze/valid_frac"] == pytest.approx(0.75)  # front: 2/2 valid, wrist: 1/2


@pytest.mark.parametrize("fam", ["paligemma", "llava"])
def test_vlm_query_modes(fam):
    model = _model(fam)
    batch = tiny_batch(model, text=6)
    T = batch["input_ids"].shape[1]
    # "last" = the last attended token: T - 1, or earlier when the sample is right-padded
    batch["attention_mask"][1, -2:] = 0
    reg = GazeRegularizer(model)
    inputs = {**batch}
    assert reg.query_positions(inputs, 2, torch.device("cpu")).tolist() == [[T - 1], [T - 3]]
    reg_l = GazeRegularizer(model, queries="labels")
    pos = reg_l.query_positions(inputs, 2, torch.device("cpu"))
    # tiny_batch supervises the last 3 tokens: positions T-4..T-2 predict them
    assert pos.shape == (2, 3) and pos[0].tolist() == list(range(T - 4, T - 1))
    with reg_l, torch.no_grad():
        model(**batch)
    assert reg_l.probe.rows(1).shape[2] == 3


def test_llava_full_strategy_skips_the_cls_token():
    model = _model("llava")
    model.config.vision_feature_select_strategy = "full"
    fam = detect_family(model)
    assert fam.tokens_per_image(model) == 17 and fam.grid_hw(model) == (4, 4)
    batch = tiny_batch(model)
    reg = GazeRegularizer(model)
    keys, _ = reg.image_positions(batch["input_ids"])
    assert keys[0].tolist() == list(range(2, 18))  # BOS at 0, CLS at 1
    with reg, torch.no_grad():
        model(**batch)
    assert reg.attention()["image"].shape == (2, 16)


def test_camera_geometry_follows_the_model_and_processor():
    pi0 = _model("pi0")
    g = camera_geometry(pi0, src_hw=(48, 64))
    assert (g.input_hw, g.patch_size, g.resize, g.pad, g.grid_hw) == ((32, 32), 8, "fit", "topleft", (4, 4))
    smol = _model("smolvlm")
    g = camera_geometry(smol)
    assert (g.pixel_shuffle, g.grid_hw, g.resize) == (2, (2, 2), "stretch")

    class Proc:
        do_image_splitting = True

    with pytest.raises(ValueError, match="do_image_splitting"):
        camera_geometry(smol, image_processor=Proc())
    llava = _model("llava")
    assert camera_geometry(llava, src_hw=(48, 64)).resize == "cover"

    class Pad:
        do_pad = True

    assert camera_geometry(llava, src_hw=(48, 64), image_processor=Pad()).resize == "fit"
