"""Tiny random transformers models and batches for the integration tests and benchmarks/bench_integrations.py
(built from configs alone, no hub access). Sizes are (image 32 px, 8 px patches) unless given; every builder is
seeded. transformers is imported on first use, so importing this module does not need it.

    model = tiny_model("pi0", n_layers=2)
    batch = tiny_batch(model, batch=2, n_cameras=2)   # the keyword arguments of model(**batch)
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor, nn

from gazereg.integrations.transformers import detect_family

FAMILY_NAMES = ("pi0", "paligemma", "idefics3", "smolvlm", "llava")
IMAGE_TOKEN_ID = 299
VOCAB = 300


def _gemma(
    hidden: int, layers: int, heads: int = 4, kv: int = 1, head_dim: int = 8, **kw: Any
) -> dict[str, Any]:
    return dict(
        model_type="gemma",
        hidden_size=hidden,
        num_hidden_layers=layers,
        intermediate_size=2 * hidden,
        num_attention_heads=heads,
        num_key_value_heads=kv,
        head_dim=head_dim,
        vocab_size=VOCAB,
        **kw,
    )


def _llama(hidden: int, layers: int) -> dict[str, Any]:
    return dict(
        model_type="llama",
        hidden_size=hidden,
        num_hidden_layers=layers,
        intermediate_size=2 * hidden,
        num_attention_heads=4,
        num_key_value_heads=2,
        vocab_size=VOCAB,
    )


def _vision(model_type: str | None, image_size: int, patch_size: int, hidden: int = 32) -> dict[str, Any]:
    d = dict(
        hidden_size=hidden,
        intermediate_size=2 * hidden,
        patch_size=patch_size,
        image_size=image_size,
        num_hidden_layers=1,
        num_attention_heads=2,
    )
    if model_type:
        d["model_type"] = model_type
    return d


def tiny_model(
    family: str,
    n_layers: int = 2,
    image_size: int = 32,
    patch_size: int = 8,
    hidden: int = 32,
    attn_implementation: str = "sdpa",
    seed: int = 0,
    chunk_size: int = 5,
) -> nn.Module:
    """A randomly initialised tiny model of one family: pi0, paligemma, idefics3, smolvlm or llava."""
    import transformers as T

    torch.manual_seed(seed)
    if family == "pi0":
        cfg = T.PI0Config(
            vlm_config=dict(
                model_type="paligemma",
                text_config=_gemma(hidden, n_layers),
                vision_config=_vision("siglip_vision_model", image_size, patch_size, hidden)
                | {"vision_use_head": False},
                projection_dim=hidden,
                image_token_id=IMAGE_TOKEN_ID,
            ),
            dit_config=_gemma(hidden // 2, n_layers),
            chunk_size=chunk_size,
            max_state_dim=4,
            max_action_dim=4,
        )
        cls = T.PI0ForConditionalGeneration
    elif family == "paligemma":
        cfg = T.PaliGemmaConfig(
            text_config=_gemma(hidden, n_layers),
            vision_config=_vision("siglip_vision_model", image_size, patch_size, hidden),
            projection_dim=hidden,
            image_token_id=IMAGE_TOKEN_ID,
        )
        cls = T.PaliGemmaForConditionalGeneration
    elif family in ("idefics3", "smolvlm"):
        conf, cls = (
            (T.Idefics3Config, T.Idefics3ForConditionalGeneration)
            if family == "idefics3"
            else (T.SmolVLMConfig, T.SmolVLMForConditionalGeneration)
        )
        cfg = conf(
            text_config=_llama(hidden, n_layers),
            vision_config=_vision(None, image_size, patch_size, hidden),
            scale_factor=2,
            image_token_id=IMAGE_TOKEN_ID,
        )
    elif family == "llava":
        cfg = T.LlavaConfig(
            text_config=_llama(hidden, n_layers),
            vision_config=_vision("clip_vision_model", image_size, patch_size, hidden)
            | {"projection_dim": hidden},
            image_token_id=IMAGE_TOKEN_ID,
            vision_feature_layer=-1,
        )
        cls = T.LlavaForConditionalGeneration
    else:
        raise ValueError(f"unknown tiny family {family!r}; use one of {FAMILY_NAMES}")
    cfg._attn_implementation = attn_implementation
    model = cls(cfg)
    return model.eval()


def tiny_batch(
    model: nn.Module, batch: int = 2, n_cameras: int = 1, text: int = 6, seed: int = 0
) -> dict[str, Tensor]:
    """Keyword arguments for `model(**batch)`: images of every camera, a prompt holding their image tokens
    (one block per camera, in camera order, after a BOS-like token) followed by `text` tokens, and the
    training targets (PI0: actions, fixed noise and timestep; VLMs: labels on the second half of the text,
    PaliGemma's token_type_ids marking that half as the suffix)."""
    g = torch.Generator().manual_seed(seed)
    fam = detect_family(model)
    size, _, _ = fam.vision(model)
    tpi = fam.tokens_per_image(model)
    T_img = n_cameras * tpi
    ids = torch.randint(1, IMAGE_TOKEN_ID - 1, (batch, 1 + T_img + text), generator=g)
    ids[:, 1 : 1 + T_img] = IMAGE_TOKEN_ID
    out: dict[str, Tensor] = {"input_ids": ids, "attention_mask": torch.ones_like(ids)}
    if fam.name == "pi0":
        cfg = model.config
        out["pixel_values"] = torch.randn(batch, n_cameras, 3, size, size, generator=g)
        out["pixel_attention_mask"] = torch.ones(batch, n_cameras, dtype=torch.bool)
        out["state"] = torch.randn(batch, cfg.max_state_dim, generator=g)
        out["actions"] = torch.randn(batch, cfg.chunk_size, cfg.max_action_dim, generator=g)
        out["noise"] = torch.randn(batch, cfg.chunk_size, cfg.max_action_dim, generator=g)
        out["timestep"] = torch.rand(batch, generator=g) * 0.9 + 0.05
        return out
    pix = torch.randn(batch * n_cameras, 3, size, size, generator=g)
    out["pixel_values"] = pix.reshape(batch, n_cameras, 3, size, size) if fam.name == "idefics3" else pix
    labels = ids.clone()
    # BOS, images and the first half of the text form the prompt; the rest is the supervised answer
    prompt = 1 + T_img + text // 2
    labels[:, :prompt] = -100
    out["labels"] = labels
    if fam.name == "paligemma":
        # prefix (bidirectional) = 0, suffix (causal) = 1, as PaliGemmaProcessor makes them
        out["token_type_ids"] = (torch.arange(ids.shape[1]) >= prompt).long().expand(batch, -1).clone()
    return out
