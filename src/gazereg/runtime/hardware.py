"""What the machine computes natively: the facts the "auto" settings (precision) are chosen from."""

from __future__ import annotations

import functools
import platform
from pathlib import Path

import torch

BF16_CPU_FLAGS = frozenset({"avx512_bf16", "amx_bf16"})
"""x86 CPU flags (Linux /proc/cpuinfo) of native bfloat16 matrix instructions"""


@functools.cache
def cpu_flags() -> frozenset[str]:
    """The CPU's feature flags from /proc/cpuinfo (empty where there is none, e.g. macOS)."""
    info = Path("/proc/cpuinfo")
    if platform.system() != "Linux" or not info.exists():
        return frozenset()
    for line in info.read_text().splitlines():
        if line.startswith("flags"):
            return frozenset(line.split(":", 1)[1].split())
    return frozenset()


def native_bf16(device_type: str) -> bool:
    """Whether `device_type` ("cpu" or "cuda") multiplies bfloat16 matrices in hardware: a CUDA GPU that
    supports bf16, or an x86 CPU with AVX-512 BF16 or AMX (where oneDNN's bf16 GEMMs beat float32)."""
    if device_type == "cuda":
        return torch.cuda.is_available() and torch.cuda.is_bf16_supported()
    return bool(cpu_flags() & BF16_CPU_FLAGS)
