#!/usr/bin/env bash
# The real-size gaze-cost benchmark (benchmarks/bench_real_size.py) on one CUDA GPU in bf16: smolvla_gaze (450M,
# 2 cameras at 512 px), pi0_gaze and pi05_gaze (4.0B / 4.1B parameters as lerobot builds them, 3 cameras at
# 224 px), batch 2, gaze / no-gaze interleaved, pi0 / pi05 with and without gradient checkpointing. About 3-5
# minutes on an H100; the benchmark itself is cut at 7 minutes (the JSON is written after each configuration).
#
#   bash benchmarks/gpu_real_size.sh            # writes $OUT/real_size_cuda.json and .log ($OUT defaults to runs/)
#   bash benchmarks/gpu_real_size.sh --rounds 4 # extra arguments go to bench_real_size.py (the last one wins)
#
# Made for a GPU machine with Python 3.12, torch 2.11.0+cu130, transformers, accelerate, safetensors, numpy,
# huggingface_hub, tokenizers, sentencepiece, einops, pillow but no lerobot and no network. The wheels it needs
# are carried in .whl/ (git-ignored; 23 MiB) and installed with --no-deps into /tmp/site, ahead of the machine's:
#   lerobot-0.6.1                 the policies (py3-none-any)
#   transformers-5.5.4            lerobot 0.6.1 needs transformers<5.6 (its pi0 subclasses transformers internals);
#                                 the lane venv's version, not the machine's 5.17
#   tokenizers-0.22.2             transformers 5.5.4 checks tokenizers<=0.23.0 at import (cp39-abi3 manylinux)
#   torchvision-0.26.0           lerobot.transforms imports it (cp312 manylinux_2_28, built for torch 2.11.0 cu130)
#   draccus-0.11.6 mergedeep-1.3.4 toml-0.10.2 typing_inspect-0.9.0 mypy_extensions-1.2.0
#                                 lerobot's config system and draccus's own dependencies
#   gymnasium-1.4.0 cloudpickle-3.1.3 farama_notifications-0.0.6
#                                 lerobot.envs (imported by lerobot.configs.train, under every policy)
#   requests-2.34.2 urllib3-2.8.0 charset_normalizer-3.5.3
#                                 lerobot.policies.molmoact2 (imported by lerobot.policies) imports requests
#   num2words-0.5.14              transformers' SmolVLMProcessor refuses to build without it
# OpenCV (cv2, a 55 MB wheel) is imported at module level by lerobot.policies.groot (pulled in by
# lerobot.policies.factory) and never called by smolvla / pi0 / pi05: where the machine has no cv2, a stub module
# that fails on any use is put LAST on PYTHONPATH (a real cv2 wins). Found by importing the benchmark's modules
# in a Python with only the machine's packages and these wheels (python -S, PYTHONPATH limited to them).
#
# Download them again (from the repository root):
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#     --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
#     --platform any -d .whl lerobot==0.6.1 transformers==5.5.4 tokenizers==0.22.2 torchvision==0.26.0 \
#     draccus==0.11.6 mergedeep==1.3.4 toml==0.10.2 typing-inspect==0.9.0 mypy_extensions==1.2.0 \
#     gymnasium==1.4.0 cloudpickle==3.1.3 farama-notifications==0.0.6 requests==2.34.2 urllib3==2.8.0 \
#     charset-normalizer==3.5.3 num2words==0.5.14
set -euo pipefail
export PYTHONUNBUFFERED=1 HF_HUB_OFFLINE=1 HF_DATASETS_OFFLINE=1 TOKENIZERS_PARALLELISM=false
cd "$(dirname "$0")/.."
OUT=${OUT:-runs}
mkdir -p "$OUT"
start=$(date +%s)

ls .whl/*.whl >/dev/null 2>&1 || { echo "gpu_real_size: error: no wheels in .whl/ (carry it: see this script's header)" >&2; exit 2; }
python3 -c 'import sys; assert sys.version_info[:2] == (3, 12), sys.version' \
    || { echo "gpu_real_size: error: the carried wheels are for Python 3.12" >&2; exit 2; }
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
STUBS=""
if ! PYTHONPATH=/tmp/site python3 -c 'import cv2' >/dev/null 2>&1; then
    mkdir -p /tmp/stubs
    cat >/tmp/stubs/cv2.py <<'EOF'
"""Stand-in for OpenCV, absent here: lerobot.policies.groot imports cv2 at module level; smolvla, pi0 and pi05
never call it. Any use fails."""


def __getattr__(name):
    raise AttributeError(f"cv2.{name}: OpenCV is not installed on this machine (a stub for lerobot's groot import)")
EOF
    STUBS=:/tmp/stubs
fi
export PYTHONPATH=/tmp/site:$PWD/src:$PWD/lerobot_plugin/src$STUBS
echo "installed in $(($(date +%s) - start)) s; cv2 stub: $([[ -n $STUBS ]] && echo yes || echo no)"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
python3 -c 'import torch, transformers, lerobot, torchvision; print("torch", torch.__version__, "cuda", torch.version.cuda,
"| transformers", transformers.__version__, "| lerobot", lerobot.__version__, "| torchvision", torchvision.__version__)'

timeout 420 python3 benchmarks/bench_real_size.py --device cuda --dtype bfloat16 --configs smolvla,pi0,pi05 \
    --batch 2 --rounds 10 --warmup 2 --gc both --out "$OUT/real_size_cuda.json" "$@" 2>&1 | tee "$OUT/real_size_cuda.log"
echo "gpu_real_size: done in $(($(date +%s) - start)) s; JSON: $OUT/real_size_cuda.json"
