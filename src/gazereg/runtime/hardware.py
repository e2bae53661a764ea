"""What the machine computes natively: the facts the "auto" settings (precision) are chosen from, and the
`NumericsKey` that says whether two runs should give identical numbers."""

from __future__ import annotations

import dataclasses
import functools
import platform
from dataclasses import dataclass
from pathlib import Path
from typing import Any

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


PRECISION_NAMES = {"no": "float32", "bf16": "bf16 mixed precision", "fp16": "fp16 mixed precision"}
"""what each resolved `--train.mixed_precision` value means, for reports"""


def auto_precision(device_type: str = "cpu") -> str:
    """What `--train.mixed_precision auto` resolves to on `device_type` here: "bf16" or "no" (float32)."""
    return "bf16" if native_bf16(device_type) else "no"


@functools.cache
def cpu_identity() -> tuple[str | None, str | None]:
    """(vendor, model name) of the CPU from /proc/cpuinfo ("GenuineIntel", "AMD EPYC 9B14"); None for either
    where it is not recorded (no /proc/cpuinfo, or an architecture whose cpuinfo lacks the field)."""
    info = Path("/proc/cpuinfo")
    lines = info.read_text().splitlines() if platform.system() == "Linux" and info.exists() else []
    fields: dict[str, str] = {}
    for line in lines:
        key, sep, value = line.partition(":")
        if sep and key.strip() in ("vendor_id", "model name"):
            fields.setdefault(key.strip(), value.strip())
    return fields.get("vendor_id"), fields.get("model name")


@dataclass(frozen=True)
class NumericsKey:
    """What, besides the code and the configuration, decides a CPU training run's floating-point results.

    Two runs of one configuration whose keys are equal are expected to give identical numbers, bit for bit
    (the project's jobs are deterministic on one machine); runs whose keys differ are expected to agree only up
    to chance. The fields are the ones that change which kernels run, or in what order they add:

    - precision: the resolved `--train.mixed_precision` ("no" = float32, "bf16", "fp16"), never "auto";
    - cpu_capability: torch's dispatch level, `torch.backends.cpu.get_cpu_capability()` ("AVX2", "AVX512",
      "DEFAULT", ...): the vectorised kernels torch picks;
    - bf16_isa: the native bfloat16 instruction sets present (sorted subset of BF16_CPU_FLAGS): oneDNN picks
      its GEMMs by them, and they decide what "auto" resolves to;
    - cpu_vendor: "GenuineIntel" or "AuthenticAMD" (None where unknown): MKL and oneDNN take vendor-specific
      code paths even at one ISA level;
    - torch: torch's version, whose kernels change between releases;
    - gpu: the CUDA device's name where torch sees one (None on a CPU-only machine): a run on a GPU machine
      may train there.

    The CPU model and the core count are recorded beside the key, not in it: the experiment fixes its threads
    per run, and two models of one vendor and ISA level run the same kernels.
    """

    precision: str
    cpu_capability: str
    bf16_isa: tuple[str, ...]
    cpu_vendor: str | None
    torch: str
    gpu: str | None = None

    @classmethod
    def here(cls, precision: str) -> NumericsKey:
        """The key of a run on this machine that trained in `precision` (resolved: not "auto")."""
        if precision not in PRECISION_NAMES:
            raise ValueError(f"precision {precision!r} is not a resolved one ({', '.join(PRECISION_NAMES)})")
        return cls(
            precision=precision,
            cpu_capability=torch.backends.cpu.get_cpu_capability(),
            bf16_isa=tuple(sorted(cpu_flags() & BF16_CPU_FLAGS)),
            cpu_vendor=cpu_identity()[0],
            torch=torch.__version__,
            gpu=torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: {"precision", "cpu_capability", "bf16_isa": [...], "cpu_vendor", "torch", "gpu"}."""
        return {**dataclasses.asdict(self), "bf16_isa": list(self.bf16_isa)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> NumericsKey:
        """The inverse of to_dict; KeyError naming the first missing field."""
        return cls(
            precision=str(d["precision"]),
            cpu_capability=str(d["cpu_capability"]),
            bf16_isa=tuple(sorted(str(f) for f in d["bf16_isa"])),
            cpu_vendor=None if d["cpu_vendor"] is None else str(d["cpu_vendor"]),
            torch=str(d["torch"]),
            gpu=None if d["gpu"] is None else str(d["gpu"]),
        )

    def describe(self, cpu_model: str | None = None) -> str:
        """One phrase: "float32 training on GenuineIntel (Intel(R) Xeon(R) Processor), torch CPU capability
        AVX512, no bf16 instructions" (the model in parentheses where given)."""
        isa = f"bf16 instructions {', '.join(self.bf16_isa)}" if self.bf16_isa else "no bf16 instructions"
        model = f" ({cpu_model})" if cpu_model else ""
        gpu = f", GPU {self.gpu}" if self.gpu else ""
        return (
            f"{PRECISION_NAMES.get(self.precision, self.precision)} training on "
            f"{self.cpu_vendor or 'an unknown CPU vendor'}{model}, torch CPU capability {self.cpu_capability}, "
            f"{isa}{gpu}"
        )

    def differences(self, other: NumericsKey) -> list[str]:
        """The fields where `other` differs, as "field: mine vs other's" phrases (empty when equal)."""
        mine, theirs = self.to_dict(), other.to_dict()
        return [f"{k}: {mine[k]} vs {theirs[k]}" for k in mine if mine[k] != theirs[k]]
