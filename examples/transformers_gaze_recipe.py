"""Gaze regularization of a transformers VLA in a few lines: transformers' native PI0 (a small random model built
from a config, no download), two cameras, gaze points -> patch distributions on each camera's patch grid -> the KL
between gaze and the action expert's attention added to PI0's flow-matching loss. Runs offline in seconds on a CPU.

    python examples/transformers_gaze_recipe.py [--family pi0|paligemma|idefics3|smolvlm|llava] [--steps 30]
    python examples/transformers_gaze_recipe.py --model path/to/local/checkpoint   # your own weights, offline

With a real checkpoint, build the batches as usual (PI0Processor / AutoProcessor) and keep the lines marked "gaze".
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
import transformers
from torch import Tensor, nn

from gazereg import heatmaps_from_points, patch_distribution
from gazereg.integrations.transformers import GazeRegularizer, camera_geometry, detect_family

IMAGE_TOKEN_ID, VOCAB = 299, 300  # the small configs' image placeholder token and vocabulary size


def small_model(family: str) -> nn.Module:
    """A randomly initialised small model of one family, built from its config alone (32 px images, 8 px patches,
    2 decoder layers): the same classes as the released checkpoints, shrunk."""
    gemma = dict(model_type="gemma", hidden_size=32, num_hidden_layers=2, intermediate_size=64)
    gemma |= dict(num_attention_heads=4, num_key_value_heads=1, head_dim=8, vocab_size=VOCAB)
    llama = dict(model_type="llama", hidden_size=32, num_hidden_layers=2, intermediate_size=64)
    llama |= dict(num_attention_heads=4, num_key_value_heads=2, vocab_size=VOCAB)
    vision = dict(hidden_size=32, intermediate_size=64, patch_size=8, image_size=32, num_hidden_layers=1)
    vision |= dict(num_attention_heads=2)
    siglip = vision | {"model_type": "siglip_vision_model"}
    torch.manual_seed(0)
    if family == "pi0":
        vlm = dict(
            model_type="paligemma", text_config=gemma, vision_config=siglip | {"vision_use_head": False}
        )
        vlm |= dict(projection_dim=32, image_token_id=IMAGE_TOKEN_ID)
        expert = gemma | dict(hidden_size=16, intermediate_size=32)  # the action expert: half the VLM's width
        config = transformers.PI0Config(
            vlm_config=vlm, dit_config=expert, chunk_size=5, max_state_dim=4, max_action_dim=4
        )
        cls = transformers.PI0ForConditionalGeneration
    elif family == "paligemma":
        config = transformers.PaliGemmaConfig(
            text_config=gemma, vision_config=siglip, projection_dim=32, image_token_id=IMAGE_TOKEN_ID
        )
        cls = transformers.PaliGemmaForConditionalGeneration
    elif family in ("idefics3", "smolvlm"):
        name = "Idefics3" if family == "idefics3" else "SmolVLM"
        config = getattr(transformers, f"{name}Config")(
            text_config=llama, vision_config=vision, scale_factor=2, image_token_id=IMAGE_TOKEN_ID
        )
        cls = getattr(transformers, f"{name}ForConditionalGeneration")
    else:  # llava
        clip = vision | {"model_type": "clip_vision_model", "projection_dim": 32}
        config = transformers.LlavaConfig(
            text_config=llama, vision_config=clip, image_token_id=IMAGE_TOKEN_ID, vision_feature_layer=-1
        )
        cls = transformers.LlavaForConditionalGeneration
    config._attn_implementation = "sdpa"
    return cls(config)


def local_model(path: Path) -> nn.Module:
    """Your own weights from a local folder (config.json + model.safetensors, as save_pretrained writes them)."""
    config = transformers.AutoConfig.from_pretrained(path, local_files_only=True)
    cls = getattr(transformers, config.architectures[0])
    return cls.from_pretrained(path, local_files_only=True, attn_implementation="sdpa")


def random_batch(model: nn.Module, batch: int, n_cameras: int, text: int = 6) -> dict[str, Tensor]:
    """Stands in for your processor and data loader: keyword arguments of `model(**batch)` with random images of
    every camera, a prompt holding their image tokens (one block per camera, in camera order, after a BOS-like
    token) followed by `text` tokens, and the training targets (PI0: actions, noise and timestep; the VLMs:
    labels on the second half of the text, PaliGemma's token_type_ids marking that half as the suffix)."""
    g = torch.Generator().manual_seed(0)
    family = detect_family(model)
    size, _, _ = family.vision(model)
    n_image = n_cameras * family.tokens_per_image(model)
    image_token = family.image_token_id(model)
    ids = torch.randint(1, image_token - 1, (batch, 1 + n_image + text), generator=g)
    ids[:, 1 : 1 + n_image] = image_token
    out: dict[str, Tensor] = {"input_ids": ids, "attention_mask": torch.ones_like(ids)}
    if family.name == "pi0":
        cfg = model.config
        chunk = (batch, cfg.chunk_size, cfg.max_action_dim)
        out["pixel_values"] = torch.randn(batch, n_cameras, 3, size, size, generator=g)
        out["pixel_attention_mask"] = torch.ones(batch, n_cameras, dtype=torch.bool)
        out["state"] = torch.randn(batch, cfg.max_state_dim, generator=g)
        out["actions"] = torch.randn(*chunk, generator=g)
        out["noise"] = torch.randn(*chunk, generator=g)
        out["timestep"] = torch.rand(batch, generator=g) * 0.9 + 0.05
        return out
    pixels = torch.randn(batch * n_cameras, 3, size, size, generator=g)
    # Idefics3 / SmolVLM take (B, n_images, 3, H, W); the others one image per row
    out["pixel_values"] = (
        pixels.reshape(batch, n_cameras, 3, size, size) if family.name == "idefics3" else pixels
    )
    prompt = 1 + n_image + text // 2  # BOS, images and the first half of the text; the rest is the answer
    out["labels"] = ids.clone()
    out["labels"][:, :prompt] = -100
    if (
        family.name == "paligemma"
    ):  # prefix (bidirectional) = 0, suffix (causal) = 1, as PaliGemmaProcessor does
        out["token_type_ids"] = (torch.arange(ids.shape[1]) >= prompt).long().expand(batch, -1).clone()
    return out


parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--family", default="pi0", choices=["pi0", "paligemma", "idefics3", "smolvlm", "llava"])
parser.add_argument(
    "--model", type=Path, help="a local checkpoint folder to regularize instead (no download)"
)
parser.add_argument("--steps", type=int, default=30)
parser.add_argument("--weight", type=float, default=1.0)
args = parser.parse_args()
torch.manual_seed(0)
torch.set_num_threads(
    1
)  # tiny tensors: thread overhead dominates, and one thread is steadier on a shared CPU

# Your model (here a small random one, or your local weights) and one batch of 4 samples with 2 cameras.
model = (small_model(args.family) if args.model is None else local_model(args.model)).train()
batch = random_batch(model, batch=4, n_cameras=2)
cameras = ("front", "wrist")

# gaze: each camera's geometry as this model sees it (input size, patch size, pixel shuffle, resize/padding).
# The stored frames are 48x64 (h, w); the model's processor fits/stretches/crops them to its input.
geometries = {cam: camera_geometry(model, src_hw=(48, 64)) for cam in cameras}

# gaze: per-frame gaze points (u right, v down, normalised) -> heatmaps -> patch distributions. In practice they
# come precomputed from `gazereg` priors (GLC predictions aggregated over time) stored with the data set.
points = {
    "front": torch.tensor([[0.25, 0.3], [0.3, 0.35], [0.7, 0.6], [0.75, 0.7]]),
    "wrist": torch.rand(4, 2),
}
gaze, valid = {}, {}
for cam in cameras:
    heat, ok = heatmaps_from_points(points[cam], size=(48, 64), sigma=3.0)
    gaze[cam], valid[cam] = patch_distribution(heat, geometries[cam], ok)

# gaze: the regularizer (layers: indices of the action expert's layers for PI0, language-model layers for VLMs;
# for your own weights the default, the second half of the layers).
reg = GazeRegularizer(model, geometries, layers=[1] if args.model is None else None, weight=args.weight)

opt = torch.optim.AdamW(model.parameters(), lr=2e-3)
first = None
for step in range(args.steps):
    with reg:  # gaze: capture attention during this forward (the model's outputs are unchanged)
        out = model(**batch)
    gaze_term, info = reg.loss(gaze, valid)  # gaze: weight * KL(gaze || attention), mean over cameras
    loss = out.loss + gaze_term  # gaze: added to the model's own loss
    opt.zero_grad()
    loss.backward()
    opt.step()
    first = info["loss/gaze_kl"] if first is None else first
    if step % 10 == 0 or step == args.steps - 1:
        print(
            f"step {step:3d}  loss/action {out.loss.item():.4f}  loss/gaze_kl {info['loss/gaze_kl']:.4f}  "
            f"gaze/patch_mass {info['gaze/patch_mass']:.3f}"
        )
print(f"{type(model).__name__}: KL(gaze||attention) {first:.4f} -> {info['loss/gaze_kl']:.4f}")
