"""gazereg.runtime.hardware.NumericsKey: which runs should give identical numbers (issue 33: the main job's
numbers depend on the CPU's precision and ISA), built from this machine's facts, equal exactly when every field
is, and stored as JSON and back."""

import dataclasses

import pytest
import torch

from gazereg.runtime import hardware
from gazereg.runtime.hardware import NumericsKey

AMD_BF16 = NumericsKey("bf16", "AVX512", ("avx512_bf16",), "AuthenticAMD", "2.13.0+cpu")


@pytest.fixture
def amd_avx2(monkeypatch):
    """This machine seen as an AMD EPYC without AVX-512 (torch dispatches AVX2 kernels, no bf16 flags)."""
    monkeypatch.setattr(hardware, "cpu_flags", lambda: frozenset({"avx2", "fma"}))
    monkeypatch.setattr(hardware, "cpu_identity", lambda: ("AuthenticAMD", "AMD EPYC 7B13"))
    monkeypatch.setattr(torch.backends.cpu, "get_cpu_capability", lambda: "AVX2")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)


def test_the_key_of_this_machine_is_its_precision_capability_bf16_isa_vendor_and_torch(amd_avx2):
    key = NumericsKey.here("no")
    assert key == NumericsKey("no", "AVX2", (), "AuthenticAMD", torch.__version__, None)
    assert hardware.auto_precision("cpu") == "no"  # without bf16 flags "auto" trains in float32
    assert key.describe("AMD EPYC 7B13") == (
        "float32 training on AuthenticAMD (AMD EPYC 7B13), torch CPU capability AVX2, no bf16 instructions"
    )


def test_the_bf16_flags_are_recorded_sorted_and_auto_resolves_to_bf16_with_them(monkeypatch, amd_avx2):
    monkeypatch.setattr(hardware, "cpu_flags", lambda: frozenset({"avx512f", "amx_bf16", "avx512_bf16"}))
    assert hardware.auto_precision("cpu") == "bf16"
    key = NumericsKey.here("bf16")
    assert key.bf16_isa == ("amx_bf16", "avx512_bf16")
    assert "bf16 mixed precision training" in key.describe() and "amx_bf16, avx512_bf16" in key.describe()


def test_an_unresolved_precision_is_refused(amd_avx2):
    with pytest.raises(ValueError, match="'auto' is not a resolved one"):
        NumericsKey.here("auto")


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("precision", "no"),  # float32 instead of bf16: the AVX2 run of issue 33
        ("cpu_capability", "AVX2"),
        ("bf16_isa", ("amx_bf16", "avx512_bf16")),
        ("cpu_vendor", "GenuineIntel"),
        ("torch", "2.14.0+cpu"),
        ("gpu", "NVIDIA H100"),
    ],
)
def test_keys_differ_when_any_field_does_and_say_which(field, value):
    other = dataclasses.replace(AMD_BF16, **{field: value})
    assert other != AMD_BF16
    (difference,) = AMD_BF16.differences(other)
    assert difference.startswith(f"{field}: ")


def test_equal_fields_are_equal_keys_through_json_whatever_the_flag_order():
    stored = AMD_BF16.to_dict()
    assert stored == {
        "precision": "bf16",
        "cpu_capability": "AVX512",
        "bf16_isa": ["avx512_bf16"],
        "cpu_vendor": "AuthenticAMD",
        "torch": "2.13.0+cpu",
        "gpu": None,
    }
    assert (
        NumericsKey.from_dict(stored) == AMD_BF16
        and AMD_BF16.differences(NumericsKey.from_dict(stored)) == []
    )
    two = dataclasses.replace(AMD_BF16, bf16_isa=("amx_bf16", "avx512_bf16"))
    flipped = {**two.to_dict(), "bf16_isa": ["avx512_bf16", "amx_bf16"]}
    assert NumericsKey.from_dict(flipped) == two
    assert hash(NumericsKey.from_dict(flipped)) == hash(two)  # usable as a dict key
    with pytest.raises(KeyError, match="torch"):
        NumericsKey.from_dict({k: v for k, v in stored.items() if k != "torch"})
