"""An offline, tiny SmolVLM backbone directory for SmolVLA smoke tests (no hub access).

    path = make_tiny_smolvlm(tmp_dir)   # config.json + tokenizer + processor, random weights at build time
    lerobot-train --policy.type=smolvla_gaze --policy.vlm_model_name=<path> --policy.load_vlm_weights=false ...

The tokenizer is a word-level vocabulary built here with SmolVLM's special image tokens; the vision tower sees
`image_size` px images in `patch_size` px patches, pixel-shuffled by `scale_factor`.
"""

from __future__ import annotations

import string
from pathlib import Path


def make_tiny_smolvlm(
    path: str | Path,
    image_size: int = 64,
    patch_size: int = 8,
    scale_factor: int = 2,
    text_layers: int = 4,
    hidden: int = 64,
) -> Path:
    from tokenizers import Tokenizer, models, pre_tokenizers
    from transformers import (
        PreTrainedTokenizerFast,
        SmolVLMConfig,
        SmolVLMImageProcessor,
        SmolVLMProcessor,
    )

    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    special = ["<pad>", "<unk>", "<|im_start|>", "<end_of_utterance>", "<fake_token_around_image>",
               "<global-img>", "<image>"]  # fmt: skip
    words = [*special, *string.ascii_lowercase, *string.digits, *".,!?;:'\"-\n"]
    words += ["the", "push", "pick", "red", "green", "square", "to", "right", "left", "up", "block", "place"]
    vocab = {w: i for i, w in enumerate(dict.fromkeys(words))}
    tok = Tokenizer(models.WordLevel(vocab=vocab, unk_token="<unk>"))
    tok.pre_tokenizer = pre_tokenizers.Whitespace()
    fast = PreTrainedTokenizerFast(
        tokenizer_object=tok,
        pad_token="<pad>",
        unk_token="<unk>",
        bos_token="<|im_start|>",
        eos_token="<end_of_utterance>",
        extra_special_tokens={
            "fake_image_token": "<fake_token_around_image>",
            "global_image_token": "<global-img>",
            "image_token": "<image>",
        },
    )
    fast.save_pretrained(path)
    heads = 4
    cfg = SmolVLMConfig(
        text_config=dict(
            model_type="llama",
            hidden_size=hidden,
            intermediate_size=2 * hidden,
            num_hidden_layers=text_layers,
            num_attention_heads=heads,
            num_key_value_heads=2,
            head_dim=hidden // heads,
            vocab_size=len(fast),
            max_position_embeddings=512,
        ),
        vision_config=dict(
            hidden_size=32,
            intermediate_size=64,
            num_hidden_layers=1,
            num_attention_heads=2,
            image_size=image_size,
            patch_size=patch_size,
        ),
        scale_factor=scale_factor,
        image_token_id=fast.convert_tokens_to_ids("<image>"),
    )
    cfg.save_pretrained(path)
    image_processor = SmolVLMImageProcessor(
        do_image_splitting=False,
        size={"longest_edge": image_size},
        max_image_size={"longest_edge": image_size},
    )
    try:
        from transformers import SmolVLMVideoProcessor

        video = SmolVLMVideoProcessor()
    except Exception:  # torchvision-less environments: SmolVLA never uses the video processor
        video = None
    kwargs = {"video_processor": video} if video is not None else {}
    proc = SmolVLMProcessor(
        image_processor=image_processor,
        tokenizer=fast,
        image_seq_len=(image_size // patch_size // scale_factor) ** 2,
        **kwargs,
    )
    proc.save_pretrained(path)
    return path


def tiny_smolvla_args(vlm_dir: str | Path) -> dict:
    """SmolVLA(Gaze)Config keyword arguments for a tiny offline policy on 64 px images over `vlm_dir`."""
    return dict(
        vlm_model_name=str(vlm_dir),
        load_vlm_weights=False,
        resize_imgs_with_padding=(64, 64),
        chunk_size=5,
        n_action_steps=5,
        num_vlm_layers=4,
        device="cpu",
        push_to_hub=False,
    )
