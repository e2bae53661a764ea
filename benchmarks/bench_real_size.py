"""The gaze term's cost at real size: SmolVLA (~450 M parameters, 512 px) and pi0 / pi0.5 (PaliGemma 3B + a 300 M
action expert, 224 px), built offline from configurations with random weights, as JSON.

    ~/.cache/gazereg/lerobot-py312/bin/python benchmarks/bench_real_size.py --device cuda --configs smolvla,pi0,pi05 \
        --out runs/real_size_cuda.json
    ... --tiny            every configuration shrunk (seconds, for the lane's test)
    ... --params-only     build on the meta device and count parameters, nothing else

Needs the LeRobot lane (Python >= 3.12 with lerobot 0.6.1 and the gazereg plugin); without lerobot it prints
{"skipped": ...} and exits 0, so benchmarks/run_all.py keeps going.

What is built (no hub access, nothing downloaded):
- smolvla: `smolvla_gaze` over a local SmolVLM2-500M-Video-Instruct configuration written here (SigLIP 768 wide, 12
  layers, 512 px in 16 px patches, pixel shuffle 4: 64 tokens per camera; a Llama text model 960 wide, 15 heads,
  5 KV heads, vocabulary 49280, of which SmolVLA keeps the first 16 layers; expert 0.75 wide) and SmolVLA's
  defaults (train_expert_only, frozen vision tower, chunk 50). The tokenizer is the plugin's word-level stand-in
  (the language token ids of the batch index the real-size embedding table). SmolVLA 0.6.1 has no gradient
  checkpointing option: measured without it.
- pi0 / pi05: `pi0_gaze` / `pi05_gaze` at lerobot's own sizes (gemma_2b + gemma_300m, SigLIP so400m at 224 px in
  14 px patches: 256 tokens per camera), every parameter trained (lerobot's defaults), with and without lerobot's
  gradient checkpointing. Reduced variants, for machines whose memory does not hold the full backward:
  `--train-expert-only` (lerobot's option: the PaliGemma VLM frozen), `--freeze-vision` (lerobot's
  freeze_vision_encoder) and `--pi-depth N` (both Gemma stacks N layers deep instead of 18, widths unchanged).

Cameras: the first (the regularized one) stores 480x640 frames, so the gaze is mapped through the policy's
resize-with-padding; the others store frames at the model's input size. The batch is model-ready (what the
pre-processor would give: normalized state and actions, language token ids and mask, images in [0, 1]) plus a
gaze point column `gaze.point` (B, 2).

One step = forward + backward + gradient clipping (norm 10 / 1, the policies' presets) + AdamW step + zeroing
the gradients, the same model alternating between the gaze term on (gaze_weight > 0: attention capture + KL) and
off (gaze_weight 0: the parent policy's forward, nothing captured), in interleaved rounds (ABBA...) after warm-up
rounds, in one process. bf16 (`--dtype auto` on a device with native bf16): autocast as lerobot-train drives it,
and for pi0 / pi05 also their own `dtype=bfloat16` (bf16 weights, fp32 vision tower). Per mode: the median step
time (seconds) and the step's peak memory (bytes; CUDA: torch.cuda.max_memory_allocated, reset before each step;
CPU: the process's peak resident set VmHWM, reset before each step through /proc/self/clear_refs), absolute and
above what was allocated before the step. Ratios are gaze / no-gaze.

Grid check (per camera): the image tokens the model embedded in a gaze step (counted by the capture) equal the
length of the gaze distribution the plugin builds for that camera, and equal the processor's image-token grid
(SmolVLM: the `<image>` tokens its processor writes for one frame; PaliGemma: (image_size / patch_size)^2 of the
model's vision configuration). Exit status 1 when any check fails (the JSON is written first).
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import gc
import json
import math
import os
import platform
import statistics
import sys
import tempfile
import time
import traceback
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path
from typing import Any

from _timing import print_markdown

CONFIGS = ("smolvla", "pi0", "pi05")
GAZE_KEY = "gaze.point"
STATE_DIM = 14
ACTION_DIM = 14
SRC_HW_FIRST = (480, 640)  # the regularized camera's stored frame: not the model's aspect, so it is padded

# SmolVLM2-500M-Video-Instruct (the backbone of lerobot's SmolVLA), as in its config.json
SMOLVLM2_500M_TEXT = dict(
    model_type="llama",
    hidden_size=960,
    intermediate_size=2560,
    num_hidden_layers=32,
    num_attention_heads=15,
    num_key_value_heads=5,
    head_dim=64,
    vocab_size=49280,
    max_position_embeddings=8192,
    rope_theta=100000.0,
    rms_norm_eps=1e-5,
    tie_word_embeddings=False,
)
SMOLVLM2_500M_VISION = dict(
    hidden_size=768,
    intermediate_size=3072,
    num_hidden_layers=12,
    num_attention_heads=12,
    image_size=512,
    patch_size=16,
)
SMOLVLM2_500M_SCALE_FACTOR = 4
SMOLVLM2_500M_IMAGE_SEQ_LEN = 64  # (512 / 16 / 4)^2


# ----- machine ---------------------------------------------------------------------------------------------------
def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def machine_info(device: str, dtype: str) -> dict[str, Any]:
    """The machine, the library versions and the precision of this run."""
    import torch

    cpuinfo = Path("/proc/cpuinfo")
    lines = cpuinfo.read_text().splitlines() if cpuinfo.exists() else []
    models = [ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("model name")]
    info: dict[str, Any] = {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpu_model": models[0] if models else platform.processor() or platform.machine(),
        "cores": len(os.sched_getaffinity(0)),
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "torch_threads": torch.get_num_threads(),
        "mem_total_gib": round(_meminfo("MemTotal") / 2**30, 1) if _meminfo("MemTotal") else None,
        "load_avg_before": [round(x, 2) for x in os.getloadavg()],
        "device": device,
        "dtype": dtype,
        "gpu": None,
        "gazereg_commit": _git_commit(),
        "versions": {
            d: _version(d)
            for d in ("torch", "lerobot", "transformers", "accelerate", "numpy", "lerobot_policy_gazereg")
        },
    }
    if device == "cuda":
        props = torch.cuda.get_device_properties(0)
        info["gpu"] = {
            "name": torch.cuda.get_device_name(0),
            "memory_gib": round(props.total_memory / 2**30, 1),
            "capability": list(torch.cuda.get_device_capability(0)),
            "cuda": torch.version.cuda,
            "bf16": torch.cuda.is_bf16_supported(),
        }
    return info


def _git_commit() -> str | None:
    """The checkout's commit (with "+dirty" when tracked files changed), or None outside a git checkout."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=10
        )
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "-uno"], cwd=root, capture_output=True, text=True, timeout=10
        )
    except (OSError, subprocess.SubprocessError):
        return None
    if head.returncode != 0:
        return None
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def _meminfo(field: str) -> int | None:
    """A /proc/meminfo field in bytes, or None."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def native_bf16(device: str) -> bool:
    """Whether `device` computes bf16 natively (CUDA: the card supports it; CPU: AMX or AVX512-BF16)."""
    import torch

    if device == "cuda":
        return torch.cuda.is_bf16_supported()
    flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    return any(f in flags.split() for f in ("amx_bf16", "avx512_bf16"))


# ----- memory --------------------------------------------------------------------------------------------------
class PeakMemory:
    """Peak memory of one step. CUDA: max_memory_allocated (reset at `start`); CPU: the process's VmHWM (reset at
    `start` by writing 5 to /proc/self/clear_refs). `start()` then `stop()` -> (peak bytes, bytes before).

    On CPU the resident set follows the live tensors only if freed memory goes back to the system: glibc's mmap
    threshold is fixed at 128 KiB (blocks above it are mapped and unmapped, not cached) and malloc_trim runs before
    each step; `allocator` says whether that was possible."""

    MMAP_THRESHOLD = 128 * 1024

    def __init__(self, device: str):
        self.device = device
        self.before = 0
        self.allocator = "cuda caching allocator" if device == "cuda" else "default"
        self._libc = None
        if device == "cpu":
            try:
                Path("/proc/self/clear_refs").write_text("5")
            except OSError as e:
                raise RuntimeError(f"cannot reset the peak RSS through /proc/self/clear_refs ({e})") from e
            with contextlib.suppress(OSError, AttributeError):
                libc = ctypes.CDLL("libc.so.6")
                if libc.mallopt(-3, self.MMAP_THRESHOLD) == 1:  # M_MMAP_THRESHOLD
                    self._libc = libc
                    self.allocator = "glibc, mmap threshold 128 KiB, malloc_trim before each step"

    @staticmethod
    def _status(field: str) -> int:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
        raise RuntimeError(f"/proc/self/status has no {field}")

    def start(self) -> None:
        import torch

        if self.device == "cuda":
            torch.cuda.synchronize()
            torch.cuda.reset_peak_memory_stats()
            self.before = torch.cuda.memory_allocated()
        else:
            gc.collect()
            if self._libc is not None:
                self._libc.malloc_trim(0)
            Path("/proc/self/clear_refs").write_text("5")
            self.before = self._status("VmRSS")

    def stop(self) -> tuple[int, int]:
        import torch

        if self.device == "cuda":
            torch.cuda.synchronize()
            return int(torch.cuda.max_memory_allocated()), int(self.before)
        return self._status("VmHWM"), int(self.before)


# ----- building ------------------------------------------------------------------------------------------------
def write_smolvlm2_500m(path: Path) -> Path:
    """A local SmolVLM2-500M-Video-Instruct directory (config.json at the real sizes, processor, word-level tokenizer
    with SmolVLM's special tokens); SmolVLA builds its VLM from it with random weights (load_vlm_weights=False)."""
    from lerobot_policy_gazereg.testing import tiny_word_tokenizer
    from transformers import SmolVLMConfig, SmolVLMImageProcessor, SmolVLMProcessor

    path.mkdir(parents=True, exist_ok=True)
    tok = tiny_word_tokenizer()
    tok.save_pretrained(path)
    cfg = SmolVLMConfig(
        text_config=dict(SMOLVLM2_500M_TEXT),
        vision_config=dict(SMOLVLM2_500M_VISION),
        scale_factor=SMOLVLM2_500M_SCALE_FACTOR,
        image_token_id=tok.convert_tokens_to_ids("<image>"),
        tie_word_embeddings=False,
    )
    cfg.save_pretrained(path)
    size = SMOLVLM2_500M_VISION["image_size"]
    image_processor = SmolVLMImageProcessor(
        do_image_splitting=False, size={"longest_edge": size}, max_image_size={"longest_edge": size}
    )
    kwargs: dict[str, Any] = {}
    with contextlib.suppress(
        Exception
    ):  # torchvision-less environments: SmolVLA never uses the video processor
        from transformers import SmolVLMVideoProcessor

        kwargs["video_processor"] = SmolVLMVideoProcessor()
    SmolVLMProcessor(
        image_processor=image_processor, tokenizer=tok, image_seq_len=SMOLVLM2_500M_IMAGE_SEQ_LEN, **kwargs
    ).save_pretrained(path)
    return path


@contextlib.contextmanager
def pi_depth(depth: int | None) -> Iterator[None]:
    """Inside: lerobot's pi0 / pi05 build both Gemma stacks `depth` layers deep (widths, heads unchanged)."""
    if depth is None:
        yield
        return
    from lerobot.policies.pi0 import modeling_pi0
    from lerobot.policies.pi05 import modeling_pi05

    saved = [(m, m.get_gemma_config) for m in (modeling_pi0, modeling_pi05)]
    for mod, orig in saved:

        def get(variant: str, _orig=orig):
            cfg = _orig(variant)
            cfg.depth = depth
            return cfg

        mod.get_gemma_config = get
    try:
        yield
    finally:
        for mod, orig in saved:
            mod.get_gemma_config = orig


def _features(cfg, cameras: list[tuple[str, tuple[int, int]]]):
    from lerobot.configs.types import FeatureType, PolicyFeature

    cfg.input_features = {k: PolicyFeature(FeatureType.VISUAL, (3, *hw)) for k, hw in cameras}
    state, action = min(STATE_DIM, cfg.max_state_dim), min(ACTION_DIM, cfg.max_action_dim)
    cfg.input_features["observation.state"] = PolicyFeature(FeatureType.STATE, (state,))
    cfg.output_features = {"action": PolicyFeature(FeatureType.ACTION, (action,))}
    return cfg


def camera_layout(n: int, input_hw: tuple[int, int], tiny: bool) -> list[tuple[str, tuple[int, int]]]:
    """(feature key, stored (H, W)) per camera: the first stores 480x640 (64x80 when tiny), the others the input size."""
    names = ["front", "wrist", "side", "top", "left", "right"]
    first = (64, 80) if tiny else SRC_HW_FIRST
    return [(f"observation.images.{names[i]}", first if i == 0 else input_hw) for i in range(n)]


def build(
    name: str, args: argparse.Namespace, workdir: Path, device: str, bf16: bool, meta: bool = False
) -> tuple[Any, dict]:
    """(policy in train mode on `device`, description) for configuration `name`; with `meta`, its parameters on
    the meta device (shapes and dtypes, no memory)."""
    import torch

    torch.manual_seed(args.seed)
    build_device = "meta" if meta else device
    if name == "smolvla":
        from lerobot_policy_gazereg.configuration_smolvla_gaze import SmolVLAGazeConfig
        from lerobot_policy_gazereg.modeling_smolvla_gaze import SmolVLAGazePolicy

        if args.tiny:
            from lerobot_policy_gazereg.testing import make_tiny_smolvlm, tiny_smolvla_args

            kw = tiny_smolvla_args(make_tiny_smolvlm(workdir / "tiny_smolvlm"))
            input_hw = (64, 64)
        else:
            kw = dict(
                vlm_model_name=str(write_smolvlm2_500m(workdir / "smolvlm2_500m")),
                load_vlm_weights=False,
                push_to_hub=False,
            )
            input_hw = tuple(SMOLVLM2_500M_VISION["image_size"] for _ in range(2))
        cams = camera_layout(args.cameras or 2, input_hw, args.tiny)
        kw.update(device=device, gaze_weight=args.gaze_weight, gaze_key=GAZE_KEY, gaze_camera=cams[0][0])
        cfg = _features(SmolVLAGazeConfig(**kw), cams)
        with torch.device(build_device):
            policy = SmolVLAGazePolicy(cfg)
        desc = {
            "policy_type": "smolvla_gaze",
            "backbone": "tiny SmolVLM (lerobot_policy_gazereg.testing)"
            if args.tiny
            else "SmolVLM2-500M config",
            "train_expert_only": cfg.train_expert_only,
            "freeze_vision_encoder": cfg.freeze_vision_encoder,
            "num_vlm_layers": cfg.num_vlm_layers,
            "param_dtype": "float32",
            "gradient_checkpointing_supported": False,
        }
    else:
        import contextlib as _cl

        from lerobot_policy_gazereg.testing import tiny_pi_args, tiny_pi_models

        if name == "pi0":
            from lerobot_policy_gazereg.configuration_pi0_gaze import PI0GazeConfig as GC
            from lerobot_policy_gazereg.modeling_pi0_gaze import PI0GazePolicy as GP
        else:
            from lerobot_policy_gazereg.configuration_pi05_gaze import PI05GazeConfig as GC
            from lerobot_policy_gazereg.modeling_pi05_gaze import PI05GazePolicy as GP
        kw = dict(tiny_pi_args()) if args.tiny else dict(push_to_hub=False)
        input_hw = tuple(kw.get("image_resolution", (224, 224)))
        cams = camera_layout(args.cameras or 3, input_hw, args.tiny)
        kw.update(
            device=device,
            dtype="bfloat16" if bf16 else "float32",
            gaze_weight=args.gaze_weight,
            gaze_key=GAZE_KEY,
            gaze_camera=cams[0][0],
            train_expert_only=args.train_expert_only,
            freeze_vision_encoder=args.freeze_vision,
        )
        cfg = _features(GC(**kw), cams)
        if meta:
            cfg.device = "meta"  # PI0Policy moves its model to config.device at the end of __init__
        sizes = tiny_pi_models() if args.tiny else _cl.nullcontext()
        with sizes, pi_depth(args.pi_depth), torch.device(build_device):
            policy = GP(cfg)
        desc = {
            "policy_type": f"{name}_gaze",
            "backbone": "tiny PaliGemma (lerobot_policy_gazereg.testing)"
            if args.tiny
            else "PaliGemma gemma_2b + gemma_300m",
            "depth": len(policy.model.paligemma_with_expert.paligemma.model.language_model.layers),
            "train_expert_only": cfg.train_expert_only,
            "freeze_vision_encoder": cfg.freeze_vision_encoder,
            "param_dtype": cfg.dtype,
            "gradient_checkpointing_supported": True,
        }
    desc.update(
        cameras={k: list(hw) for k, hw in cams},
        input_hw=list(input_hw),
        chunk_size=cfg.chunk_size,
        tokenizer_max_length=cfg.tokenizer_max_length,
        gaze_camera=cams[0][0],
        gaze_layers=list(policy.gaze_capture.layers),
        gaze_weight=args.gaze_weight,
        params_total=sum(p.numel() for p in policy.parameters()),
        params_trainable=sum(p.numel() for p in policy.parameters() if p.requires_grad),
    )
    if not meta:
        policy.to(device)
        policy.train()
    return policy, desc


def make_batch(policy, batch_size: int, device: str, seed: int) -> dict:
    """A model-ready training batch: images (B, 3, H, W) in [0, 1] at each camera's stored size, normalized state
    (B, state dim) and actions (B, chunk, action dim) (STATE_DIM / ACTION_DIM, at most the config's max), language token ids and mask, and `gaze.point` (B, 2)."""
    import torch

    cfg = policy.config
    g = torch.Generator().manual_seed(seed)
    batch: dict[str, Any] = {}
    for key, feat in cfg.image_features.items():
        batch[key] = torch.rand(batch_size, *feat.shape, generator=g)
    state, action = cfg.input_features["observation.state"].shape[0], cfg.output_features["action"].shape[0]
    batch["observation.state"] = torch.randn(batch_size, state, generator=g)
    batch["action"] = torch.randn(batch_size, cfg.chunk_size, action, generator=g)
    batch["action_is_pad"] = torch.zeros(batch_size, cfg.chunk_size, dtype=torch.bool)
    n = int(cfg.tokenizer_max_length)
    batch["observation.language.tokens"] = torch.randint(4, 40, (batch_size, n), generator=g)
    batch["observation.language.attention_mask"] = torch.ones(batch_size, n, dtype=torch.bool)
    batch[GAZE_KEY] = 0.1 + 0.8 * torch.rand(batch_size, 2, generator=g)
    return {k: v.to(device) for k, v in batch.items()}


# ----- the grid check ----------------------------------------------------------------------------------------
def processor_grid(name: str, policy) -> int:
    """Image tokens per camera frame on the processor's side: SmolVLM's processor (the `<image>` tokens it writes
    for one frame at the input size); PaliGemma: (image_size / patch_size)^2 of the model's vision config."""
    if name == "smolvla":
        import numpy as np

        proc = policy.model.vlm_with_expert.processor
        w, h = policy.config.resize_imgs_with_padding
        frame = np.zeros((h, w, 3), dtype=np.uint8)
        ids = proc(text=["<image>"], images=[[frame]], return_tensors="pt")["input_ids"][0]
        image_id = proc.tokenizer.convert_tokens_to_ids("<image>")
        return int((ids == image_id).sum())
    vcfg = policy.model.paligemma_with_expert.paligemma.config.vision_config
    return int((vcfg.image_size // vcfg.patch_size) ** 2)


def grid_check(name: str, policy, batch: dict) -> dict[str, Any]:
    """Per camera: image tokens seen by the model in the last gaze step, the length of the gaze distribution the
    plugin builds for it, the processor's grid; `ok` when all three agree for every camera and the captured
    attention of the regularized camera has its gaze distribution's length."""
    from lerobot_policy_gazereg.gaze_targets import gaze_distribution, smolvla_geometry
    from lerobot_policy_gazereg.modeling_pi0_gaze import pi_geometry

    cfg = policy.config
    seen = policy.gaze_capture.image_tokens
    cams = list(cfg.image_features)
    grid = processor_grid(name, policy)
    out: dict[str, Any] = {"processor_grid": grid, "cameras": {}}
    ok = len(seen) == len(cams)
    for i, cam in enumerate(cams):
        src_hw = tuple(int(x) for x in cfg.image_features[cam].shape[-2:])
        if name == "smolvla":
            vcfg = policy.model.vlm_with_expert.config
            geom, flip = smolvla_geometry(
                src_hw, cfg.resize_imgs_with_padding, vcfg.vision_config.patch_size, vcfg.scale_factor
            )
        else:
            patch = policy.model.paligemma_with_expert.paligemma.config.vision_config.patch_size
            geom, flip = pi_geometry(src_hw, tuple(int(x) for x in cfg.image_resolution), patch), False
        dist, _ = gaze_distribution(batch[GAZE_KEY].cpu(), geom, flip, cfg.gaze_sigma, src_hw)
        n_seen = seen[i] if i < len(seen) else None
        row = {
            "stored_hw": list(src_hw),
            "tokens_seen": n_seen,
            "gaze_len": int(dist.shape[1]),
            "grid": list(geom.grid_hw),
        }
        row["ok"] = n_seen == row["gaze_len"] == grid
        ok = ok and row["ok"]
        out["cameras"][cam] = row
    attn = policy.gaze_capture.attention()
    gaze_cam = cfg.gaze_camera_key()
    out["attention_len"] = int(attn.shape[-1])
    out["attention_ok"] = out["attention_len"] == out["cameras"][gaze_cam]["gaze_len"]
    out["ok"] = bool(ok and out["attention_ok"])
    return out


# ----- the measurement ---------------------------------------------------------------------------------------
def set_checkpointing(policy, on: bool) -> None:
    if on:
        policy.model.gradient_checkpointing_enable()
    else:
        policy.model.gradient_checkpointing_disable()


def run_config(name: str, policy, desc: dict, args, device: str, bf16: bool) -> dict[str, Any]:
    """Interleaved gaze / no-gaze training steps, with and without gradient checkpointing where supported."""
    import torch

    trainable = [p for p in policy.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(trainable, lr=1e-6, betas=(0.9, 0.95), weight_decay=0.01)
    clip = float(getattr(policy.config, "optimizer_grad_clip_norm", 1.0))
    batch = make_batch(policy, args.batch, device, args.seed)
    weight = float(args.gaze_weight)
    autocast = torch.autocast(device_type=device, dtype=torch.bfloat16, enabled=bf16)
    mem = PeakMemory(device)
    infos: dict[str, dict] = {}

    def step(mode: str) -> tuple[float, int, int]:
        policy.config.gaze_weight = weight if mode == "gaze" else 0.0
        mem.start()
        t0 = time.perf_counter()
        with autocast:
            loss, info = policy.forward(dict(batch))
        loss.backward()
        if (
            "params_with_grad" not in desc
        ):  # trainable parameters the loss reaches (lerobot's pi heads it does not)
            desc["params_with_grad"] = sum(p.numel() for p in trainable if p.grad is not None)
        torch.nn.utils.clip_grad_norm_(trainable, clip)
        opt.step()
        opt.zero_grad(set_to_none=True)
        if device == "cuda":
            torch.cuda.synchronize()
        dt = time.perf_counter() - t0
        peak, before = mem.stop()
        infos[mode] = {k: v for k, v in info.items() if isinstance(v, int | float)} | {
            "loss": float(loss.detach())
        }
        return dt, peak, before

    # SmolVLA 0.6.1 has no gradient checkpointing: it runs without, whatever --gc says
    gc_modes = {"both": [False, True], "on": [True], "off": [False]}[args.gc]
    if not desc["gradient_checkpointing_supported"]:
        gc_modes = [False]
    runs = []
    grid = None
    for ckpt in gc_modes:
        if desc["gradient_checkpointing_supported"]:
            set_checkpointing(policy, ckpt)
        for _ in range(args.warmup):
            for mode in ("gaze", "plain"):
                step(mode)
        steps: dict[str, list] = {"gaze": [], "plain": []}
        for r in range(args.rounds):
            order = ("gaze", "plain") if r % 2 == 0 else ("plain", "gaze")
            for mode in order:
                steps[mode].append(step(mode))
            print(f"  {name} gc={ckpt} round {r + 1}/{args.rounds}: "
                  f"gaze {steps['gaze'][-1][0]:.3f}s plain {steps['plain'][-1][0]:.3f}s", file=sys.stderr, flush=True)  # fmt: skip
        if grid is None:  # the capture keeps the last gaze step's state (a plain step captures nothing)
            grid = grid_check(name, policy, batch)
        runs.append(summarize(ckpt, steps, infos))
    policy.config.gaze_weight = weight
    return {"runs": runs, "grid_check": grid, "memory_measure": mem.allocator}


def summarize(ckpt: bool, steps: dict[str, list], infos: dict[str, dict]) -> dict[str, Any]:
    per = {}
    for mode, rows in steps.items():
        times = [r[0] for r in rows]
        peaks = [r[1] for r in rows]
        above = [r[1] - r[2] for r in rows]
        per[mode] = {
            "step_s_median": statistics.median(times),
            "step_s": [round(t, 5) for t in times],
            "peak_bytes": max(peaks),
            "peak_above_before_bytes": max(above),
            "info": infos.get(mode, {}),
        }
    g, p = per["gaze"], per["plain"]
    ratio = {
        "time": g["step_s_median"] / p["step_s_median"],
        "peak_memory": g["peak_bytes"] / p["peak_bytes"],
        "step_memory": g["peak_above_before_bytes"] / max(p["peak_above_before_bytes"], 1),
    }
    return {
        "gradient_checkpointing": ckpt,
        "rounds": len(steps["gaze"]),
        "gaze": g,
        "plain": p,
        "ratio": ratio,
    }


# ----- memory fit -----------------------------------------------------------------------------------------------
def needed_bytes(policy) -> int:
    """Weights + gradients + AdamW's two moments (each in its parameter's dtype) of `policy`, in bytes."""
    total = 0
    for p in policy.parameters():
        size = p.numel() * p.element_size()
        total += size * (4 if p.requires_grad else 1)
    return total


def available_bytes(device: str) -> int:
    import torch

    if device == "cuda":
        return int(torch.cuda.mem_get_info()[0])
    return int(_meminfo("MemAvailable") or 0)


# ----- CLI ----------------------------------------------------------------------------------------------------------
class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, exit status 2 (argparse would print the usage first)
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = _Parser(
        prog="bench_real_size", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--configs", default="smolvla,pi0,pi05", help="comma-separated, from smolvla, pi0, pi05")
    ap.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    ap.add_argument("--dtype", choices=("auto", "float32", "bfloat16"), default="auto",
                    help="auto: bfloat16 where the device computes it natively, else float32")  # fmt: skip
    ap.add_argument("--rounds", type=int, default=5, help="timed rounds (one gaze + one plain step each)")
    ap.add_argument("--warmup", type=int, default=1, help="untimed rounds first, per checkpointing setting")
    ap.add_argument("--batch", type=int, default=2)
    ap.add_argument("--cameras", type=int, default=None, help="cameras (default: smolvla 2, pi0 / pi05 3)")
    ap.add_argument("--gc", choices=("both", "on", "off"), default="both",
                    help="gradient checkpointing (pi0 / pi05; smolvla has none and runs 'off' only)")  # fmt: skip
    ap.add_argument("--gaze-weight", type=float, default=0.1, help="the gaze mode's gaze_weight (> 0)")
    ap.add_argument("--train-expert-only", action="store_true", help="pi0 / pi05: freeze the PaliGemma VLM")
    ap.add_argument("--freeze-vision", action="store_true", help="pi0 / pi05: freeze the vision tower")
    ap.add_argument(
        "--pi-depth", type=int, default=None, help="pi0 / pi05: Gemma layers (default: lerobot's 18)"
    )
    ap.add_argument("--tiny", action="store_true", help="shrink every configuration (the lane's test)")
    ap.add_argument("--params-only", action="store_true", help="build on the meta device, count parameters")
    ap.add_argument("--no-fit-check", action="store_true",
                    help="run a configuration even where weights + gradients + AdamW exceed the free memory")  # fmt: skip
    ap.add_argument("--threads", type=int, default=None, help="CPU threads (default: torch's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="JSON path (default: stdout only)")
    ap.add_argument(
        "--markdown", type=Path, default=None, metavar="JSON",
        help="measure nothing: print the markdown table of a JSON this script wrote (for docs)",
    )  # fmt: skip
    args = ap.parse_args(argv)
    names = [c.strip() for c in args.configs.split(",") if c.strip()]
    bad = [c for c in names if c not in CONFIGS]
    if bad or not names:
        ap.error(f"--configs: unknown {bad or 'empty'}; choose from {', '.join(CONFIGS)}")
    if len(set(names)) != len(names):
        ap.error(f"--configs: {args.configs!r} names a configuration twice")
    args.config_names = names
    if args.rounds < 1:
        ap.error(f"--rounds must be >= 1, got {args.rounds}")
    if args.warmup < 0:
        ap.error(f"--warmup must be >= 0, got {args.warmup}")
    if args.batch < 1:
        ap.error(f"--batch must be >= 1, got {args.batch}")
    if args.cameras is not None and not 1 <= args.cameras <= 6:
        ap.error(f"--cameras must be in 1..6, got {args.cameras}")
    if not (math.isfinite(args.gaze_weight) and args.gaze_weight > 0):
        ap.error(f"--gaze-weight must be a finite number > 0, got {args.gaze_weight}")
    if args.pi_depth is not None and not 1 <= args.pi_depth <= 18:
        ap.error(f"--pi-depth must be in 1..18, got {args.pi_depth}")
    if args.threads is not None and args.threads < 1:
        ap.error(f"--threads must be >= 1, got {args.threads}")
    if args.out is not None and args.out.exists() and args.out.is_dir():
        ap.error(f"--out {args.out} is a directory; give a file path")
    return args


def write_json(path: Path, result: dict[str, Any]) -> None:
    """Write `result` to `path` atomically (a reader never sees a half-written file)."""
    from gazereg.runtime.io import atomic_write_json

    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, result)


def measure(name: str, args: argparse.Namespace, workdir: Path, bf16: bool) -> dict[str, Any]:
    """The JSON entry of one configuration: its model, and its runs and grid check (or why it was skipped).

    The model is first built on the meta device to see whether it fits: weights + gradients + AdamW's moments, and
    the float32 weights lerobot's pi0 / pi05 hold while building before casting to bf16, against the device's free
    memory (before activations)."""
    shapes, desc = build(name, args, workdir, args.device, bf16, meta=True)
    desc["weights_grads_adam_bytes"] = needed_bytes(shapes)
    build_bytes = 4 * desc["params_total"]
    del shapes
    entry: dict[str, Any] = {"model": desc}
    if args.params_only:
        return entry
    need, free = max(desc["weights_grads_adam_bytes"], build_bytes), available_bytes(args.device)
    if need > free and not args.no_fit_check:
        entry["skipped"] = (
            f"weights + gradients + AdamW need {need / 2**30:.1f} GiB before activations, {free / 2**30:.1f} GiB "
            "free (--train-expert-only / --freeze-vision / --pi-depth reduce it; --no-fit-check runs anyway)"
        )
        print(f"  skipped: {entry['skipped']}", file=sys.stderr)
        return entry
    t0 = time.perf_counter()
    policy, desc = build(name, args, workdir, args.device, bf16)
    desc["build_s"] = round(time.perf_counter() - t0, 2)
    desc["weights_grads_adam_bytes"] = entry["model"]["weights_grads_adam_bytes"]
    entry["model"] = desc
    entry.update(run_config(name, policy, desc, args, args.device, bf16))
    return entry


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.markdown is not None:
        return print_markdown(args.markdown, markdown_table, "bench_real_size.py")
    try:
        import lerobot  # noqa: F401
        import lerobot_policy_gazereg  # noqa: F401
    except ImportError as e:
        print(json.dumps({"skipped": f"needs the LeRobot lane (lerobot 0.6.1 + the gazereg plugin): {e}"}))
        return 0
    import torch

    if args.device == "cuda" and not torch.cuda.is_available():
        print("bench_real_size: error: --device cuda but torch sees no CUDA device", file=sys.stderr)
        return 2
    if args.threads:
        torch.set_num_threads(args.threads)
    bf16 = native_bf16(args.device) if args.dtype == "auto" else args.dtype == "bfloat16"
    dtype = "bfloat16" if bf16 else "float32"
    result: dict[str, Any] = {
        "benchmark": "bench_real_size",
        "argv": sys.argv[1:] if argv is None else list(argv),
        "machine": machine_info(args.device, dtype),
        "settings": {
            "batch": args.batch,
            "rounds": args.rounds,
            "warmup": args.warmup,
            "gaze_weight": args.gaze_weight,
            "tiny": args.tiny,
            "params_only": args.params_only,
            "train_expert_only": args.train_expert_only,
            "freeze_vision": args.freeze_vision,
            "pi_depth": args.pi_depth,
            "autocast_bf16": bf16,
        },
        "configs": {},
    }
    failed = False
    with tempfile.TemporaryDirectory(prefix="bench_real_size_") as tmp:
        for name in args.config_names:
            print(f"== {name}", file=sys.stderr, flush=True)
            try:
                entry = measure(name, args, Path(tmp) / name, bf16)
            except Exception as e:  # one configuration failing (e.g. out of memory) must not lose the others
                tb = traceback.format_exc()
                entry = {"error": f"{type(e).__name__}: {e}", "traceback_tail": tb[-3000:]}
                print(tb, file=sys.stderr)
            failed = failed or "error" in entry or not entry.get("grid_check", {"ok": True})["ok"]
            result["configs"][name] = entry
            if args.out is not None:  # after each configuration: a run cut short keeps what it measured
                write_json(args.out, result)
            gc.collect()
            if args.device == "cuda":
                torch.cuda.empty_cache()
    if args.out is not None:
        write_json(args.out, result)
        print(f"wrote {args.out}", file=sys.stderr)
    if args.out is None:
        print(json.dumps(result, indent=2, sort_keys=True))
        print(summary_table(result), file=sys.stderr)
    else:
        print(summary_table(result))
    return 1 if failed else 0


def summary_table(result: dict[str, Any]) -> str:
    """One line per configuration and checkpointing setting: median step times, peak memory and the gaze / no-gaze
    ratios (time, peak memory, memory above what was allocated before the step), and the grid check."""
    m = result["machine"]
    gpu = (m.get("gpu") or {}).get("name")
    head = (
        f"device {m['device']} ({gpu or m['cpu_model']}), dtype {m['dtype']}, torch {m['versions']['torch']}"
    )
    rows = [head, f"{'config':8} {'params':>7} {'gc':>3} {'gaze s':>8} {'plain s':>8} {'time x':>7} "
            f"{'gaze GiB':>8} {'plain GiB':>9} {'peak x':>7} {'step x':>7} {'grid':>5}"]  # fmt: skip
    for name, e in result["configs"].items():
        if "error" in e:
            rows.append(f"{name:8} ERROR {e['error'][:200]}")
            continue
        params = f"{e['model']['params_total'] / 1e6:.0f}M"
        if "runs" not in e:
            rows.append(f"{name:8} {params:>7} {e.get('skipped', 'parameters counted only')}")
            continue
        grid = "ok" if e["grid_check"]["ok"] else "FAIL"
        for r in e["runs"]:
            g, p, q = r["gaze"], r["plain"], r["ratio"]
            rows.append(
                f"{name:8} {params:>7} {'on' if r['gradient_checkpointing'] else 'off':>3} "
                f"{g['step_s_median']:8.3f} {p['step_s_median']:8.3f} {q['time']:7.3f} "
                f"{g['peak_bytes'] / 2**30:8.2f} {p['peak_bytes'] / 2**30:9.2f} {q['peak_memory']:7.3f} "
                f"{q['step_memory']:7.3f} {grid:>5}"
            )
    return "\n".join(rows)


def markdown_table(result: dict[str, Any], source: str) -> str:
    """The `summary_table` facts as a markdown table under a line naming the machine, the settings and `source`
    (the JSON file), for docs; medians of `settings.rounds` interleaved rounds."""
    m, s = result["machine"], result["settings"]
    gpu = (m.get("gpu") or {}).get("name")
    where = f"{gpu} (CUDA {m['gpu']['cuda']})" if gpu else f"{m['cpu_model']}, {m.get('cores')} cores"
    lines = [
        f"`{source}`: {where}, {m['dtype']}, torch {m['versions']['torch']}, lerobot {m['versions']['lerobot']}, "
        f"transformers {m['versions']['transformers']}; batch {s['batch']}, {s['rounds']} interleaved rounds "
        f"(medians), gaze weight {s['gaze_weight']}"
        + (f", Gemma depth {s['pi_depth']}" if s.get("pi_depth") else "")
        + (", expert only" if s.get("train_expert_only") else "")
        + ".",
        "",
        "| config | parameters (with grad) | checkpointing | step s gaze / plain | time x | peak GiB gaze / plain "
        "| peak x | step memory x | token grid |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, e in result["configs"].items():
        if "runs" not in e:
            lines.append(f"| {name} | | | {e.get('error') or e.get('skipped', 'not run')} | | | | | |")
            continue
        md = e["model"]
        params = f"{md['params_total'] / 1e6:.0f}M ({md.get('params_with_grad', 0) / 1e6:.0f}M)"
        cams = e["grid_check"]["cameras"]
        grid = ", ".join(f"{c['tokens_seen']}" for c in cams.values()) + (
            " ok" if e["grid_check"]["ok"] else " FAIL"
        )
        for r in e["runs"]:
            g, p, q = r["gaze"], r["plain"], r["ratio"]
            lines.append(
                f"| {name} | {params} | {'on' if r['gradient_checkpointing'] else 'off'} | "
                f"{g['step_s_median']:.3f} / {p['step_s_median']:.3f} | {q['time']:.3f} | "
                f"{g['peak_bytes'] / 2**30:.2f} / {p['peak_bytes'] / 2**30:.2f} | {q['peak_memory']:.3f} | "
                f"{q['step_memory']:.3f} | {grid} |"
            )
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
