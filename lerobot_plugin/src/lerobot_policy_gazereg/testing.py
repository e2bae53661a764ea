"""An offline, tiny SmolVLM backbone directory for SmolVLA smoke tests (no hub access).

    path = make_tiny_smolvlm(tmp_dir)   # config.json + tokenizer + processor, random weights at build time
    lerobot-train --policy.type=smolvla_gaze --policy.vlm_model_name=<path> --policy.load_vlm_weights=false ...

The tokenizer is a word-level vocabulary built here with SmolVLM's special image tokens; the vision tower sees
`image_size` px images in `patch_size` px patches, pixel-shuffled by `scale_factor`.
"""

from __future__ import annotations

import contextlib
import string
from collections.abc import Callable
from pathlib import Path


def tiny_word_tokenizer():
    """A word-level fast tokenizer over letters, digits, punctuation, a few task words and SmolVLM's special
    image tokens (a `transformers.PreTrainedTokenizerFast`)."""
    from tokenizers import Tokenizer, models, pre_tokenizers
    from transformers import PreTrainedTokenizerFast

    special = ["<pad>", "<unk>", "<|im_start|>", "<end_of_utterance>", "<fake_token_around_image>",
               "<global-img>", "<image>"]  # fmt: skip
    words = [*special, *string.ascii_lowercase, *string.digits, *".,!?;:'\"-\n"]
    words += ["the", "push", "pick", "red", "green", "square", "to", "right", "left", "up", "block", "place"]
    vocab = {w: i for i, w in enumerate(dict.fromkeys(words))}
    tok = Tokenizer(models.WordLevel(vocab=vocab, unk_token="<unk>"))
    tok.pre_tokenizer = pre_tokenizers.Whitespace()
    return PreTrainedTokenizerFast(
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


def make_tiny_smolvlm(
    path: str | Path,
    image_size: int = 64,
    patch_size: int = 8,
    scale_factor: int = 2,
    text_layers: int = 4,
    hidden: int = 64,
) -> Path:
    from transformers import SmolVLMConfig, SmolVLMImageProcessor, SmolVLMProcessor

    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    fast = tiny_word_tokenizer()
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


# ----- tiny offline pi0 / pi0.5 (PaliGemma + Gemma expert) -----------------------------------------------------
# LeRobot builds pi0/pi0.5 at the fixed sizes of `paligemma_variant` / `action_expert_variant` (gemma_2b +
# SigLIP so400m: ~3B parameters) and tokenizes with the hub tokenizer `google/paligemma-3b-pt-224`. For offline
# smoke tests, `tiny_pi_models()` shrinks both variants and the vision tower (the module structure, hence the
# state-dict keys, is unchanged), and `make_offline_paligemma_cache()` places a tiny word-level tokenizer in a
# hub cache under that repo id, so `HF_HUB_OFFLINE=1` resolves it without the network.

PALIGEMMA_TOKENIZER = "google/paligemma-3b-pt-224"
PI_HEADS = 8  # lerobot's pi0/pi05 joint attention reshapes to 8 heads: the tiny configs keep 8


def _tiny_gemma_config(module, variant: str, widths: dict[str, int], depth: int, head_dim: int):
    """A GemmaConfig of lerobot's pi modeling module for `variant`, at the tiny `widths[variant]`."""
    if variant not in widths:
        raise ValueError(f"Unknown variant: {variant}")
    w = widths[variant]
    return module.GemmaConfig(
        width=w, depth=depth, mlp_dim=2 * w, num_heads=PI_HEADS, num_kv_heads=1, head_dim=head_dim
    )


def install_tiny_pi_models(
    vlm_width: int = 32,
    expert_width: int = 16,
    depth: int = 2,
    head_dim: int = 8,
    vision_width: int = 32,
    patch_size: int = 14,
) -> Callable[[], None]:
    """Make lerobot's pi0 and pi05 build tiny models (process-wide); returns a function that undoes it.

    gemma_2b -> width `vlm_width`, gemma_300m -> width `expert_width`, both `depth` layers of 8 heads x
    `head_dim`; the SigLIP tower: one layer of `vision_width`, `patch_size` px patches, projected to the VLM width.
    """
    from lerobot.policies.pi0 import modeling_pi0
    from lerobot.policies.pi05 import modeling_pi05
    from torch import nn
    from transformers import CONFIG_MAPPING, PaliGemmaConfig

    widths = {"gemma_2b": vlm_width, "gemma_300m": expert_width}
    vision = dict(hidden_size=vision_width, num_hidden_layers=1, num_attention_heads=2, patch_size=patch_size)

    class _Mapping(dict):
        def __getitem__(self, key):
            if key == "paligemma":
                return lambda **kw: PaliGemmaConfig(vision_config=dict(vision), **kw)
            return CONFIG_MAPPING[key]

    undo = []
    for mod in (modeling_pi0, modeling_pi05):
        cls = mod.PaliGemmaWithExpertModel
        orig_init, orig_get, orig_map = cls.__init__, mod.get_gemma_config, mod.CONFIG_MAPPING

        def init(self, vlm_config, *args, _orig=orig_init, **kwargs):
            _orig(self, vlm_config, *args, **kwargs)
            # lerobot fixes the projection to 2048 (gemma_2b's width): project to the tiny VLM width instead
            vcfg = self.paligemma.config.vision_config
            vcfg.projection_dim = vlm_config.width
            self.paligemma.model.multi_modal_projector.linear = nn.Linear(vcfg.hidden_size, vlm_config.width)
            self._set_requires_grad()

        def get(variant, _mod=mod):
            return _tiny_gemma_config(_mod, variant, widths, depth, head_dim)

        cls.__init__, mod.get_gemma_config, mod.CONFIG_MAPPING = init, get, _Mapping()
        undo.append((mod, cls, orig_init, orig_get, orig_map))

    def restore() -> None:
        for mod, cls, i, g, m in undo:
            cls.__init__, mod.get_gemma_config, mod.CONFIG_MAPPING = i, g, m

    return restore


@contextlib.contextmanager
def tiny_pi_models(**kwargs):
    """Context manager form of `install_tiny_pi_models` (restores lerobot's sizes on exit)."""
    restore = install_tiny_pi_models(**kwargs)
    try:
        yield
    finally:
        restore()


def make_tiny_paligemma_tokenizer(path: str | Path) -> Path:
    """A word-level fast tokenizer (saved at `path`) standing in for PaliGemma's in offline tests."""
    from tokenizers import Tokenizer, models, normalizers, pre_tokenizers
    from transformers import PreTrainedTokenizerFast

    path = Path(path)
    words = ["<pad>", "<eos>", "<bos>", "<unk>", *string.ascii_lowercase, *string.digits, *".,!?;:'\"-\n"]
    words += ["task", "state", "action", "the", "push", "pick", "red", "green", "block", "to", "place"]
    vocab = {w: i for i, w in enumerate(dict.fromkeys(words))}
    tok = Tokenizer(models.WordLevel(vocab=vocab, unk_token="<unk>"))
    tok.normalizer = normalizers.Lowercase()
    tok.pre_tokenizer = pre_tokenizers.Whitespace()
    fast = PreTrainedTokenizerFast(
        tokenizer_object=tok, pad_token="<pad>", unk_token="<unk>", bos_token="<bos>", eos_token="<eos>"
    )
    fast.save_pretrained(path)
    (path / "config.json").write_text("{}")  # AutoTokenizer reads a model config first; an empty one will do
    return path


def make_offline_paligemma_cache(hub_cache: str | Path) -> Path:
    """A hub cache directory (use it as HF_HUB_CACHE) holding a tiny tokenizer as `google/paligemma-3b-pt-224`."""
    hub_cache = Path(hub_cache)
    repo = hub_cache / ("models--" + PALIGEMMA_TOKENIZER.replace("/", "--"))
    commit = "0" * 40
    make_tiny_paligemma_tokenizer(repo / "snapshots" / commit)
    (repo / "refs").mkdir(parents=True, exist_ok=True)
    (repo / "refs" / "main").write_text(commit)
    return hub_cache


def tiny_pi_args() -> dict:
    """PI0(Gaze)Config / PI05(Gaze)Config keyword arguments for tiny offline policies (inside tiny_pi_models())."""
    return dict(
        image_resolution=(56, 56),
        chunk_size=5,
        n_action_steps=5,
        max_state_dim=8,
        max_action_dim=8,
        tokenizer_max_length=32,
        num_inference_steps=2,
        device="cpu",
        push_to_hub=False,
    )
