"""Training precision (898cbce): mixed_precision "auto" resolved from what the device multiplies natively and
recorded in config.json, resumes that keep it, a deterministic bf16 path, and the fused AdamW."""

import dataclasses
import json
import platform
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from gazereg.runtime import hardware
from gazereg.runtime.config import ConfigMismatch
from gazereg.training import setup as training_setup
from gazereg.training.checkpoint import list_checkpoints
from gazereg.training.config import GazeConfig, smoke
from gazereg.training.loop import train
from gazereg.training.setup import make_optimiser, resolve_precision

OTHER = {"bf16": "no", "no": "bf16"}


def cfg(store, run_dir, **kw):
    base = smoke()
    data = dataclasses.replace(base.data, store=Path(store.root), val_fraction=0.25)
    return dataclasses.replace(base, run_dir=Path(run_dir), data=data, **kw)


def weights(run_dir, step, name="model.safetensors"):
    return load_file(str(Path(run_dir) / "checkpoints" / f"step_{step:06d}" / name))


OPT = "training_state/optimizer.safetensors"


@pytest.fixture
def train_fresh(reset_accelerate):
    """`train` as in its own process: accelerate keeps one mixed precision per process and refuses an
    Accelerator with another one, and tests here train in both (each test starts with a clean state:
    tests/conftest.py's `_fresh_accelerate`)."""

    def run(c):
        reset_accelerate()
        return train(c)

    return run


# ----- 6. resolve_precision ---------------------------------------------------------------------------------
@pytest.mark.parametrize(("native", "expected"), [(True, "bf16"), (False, "no")])
def test_auto_precision_follows_the_device(monkeypatch, native, expected):
    asked = []

    def fake_native_bf16(device_type):
        asked.append(device_type)
        return native

    monkeypatch.setattr(training_setup, "native_bf16", fake_native_bf16)
    c = dataclasses.replace(smoke(), device="cpu")
    assert c.mixed_precision == "auto"  # the default
    out = resolve_precision(c)
    assert out.mixed_precision == expected and asked == ["cpu"]
    assert type(out) is type(c) and out is not c and c.mixed_precision == "auto"  # a new config
    assert dataclasses.replace(out, mixed_precision="auto") == c  # nothing else changed
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_precision(dataclasses.replace(c, device="auto")).mixed_precision == expected
    assert asked == ["cpu", "cpu"]  # device auto without a GPU asks about the CPU
    assert resolve_precision(dataclasses.replace(c, device="cuda")).mixed_precision == expected
    assert asked == ["cpu", "cpu", "cuda"]


@pytest.mark.parametrize("explicit", ["no", "bf16", "fp16"])
def test_explicit_precision_is_kept(monkeypatch, explicit):
    def must_not_ask(device_type):
        raise AssertionError("an explicit precision needs no hardware query")

    monkeypatch.setattr(training_setup, "native_bf16", must_not_ask)
    c = dataclasses.replace(smoke(), mixed_precision=explicit)
    out = resolve_precision(c)
    assert out == c and out.mixed_precision == explicit


# ----- 7. the CPU flags ---------------------------------------------------------------------------------------
@pytest.mark.skipif(
    platform.system() != "Linux" or not Path("/proc/cpuinfo").exists(), reason="needs Linux /proc/cpuinfo"
)
def test_cpu_flags_and_native_bf16_agree_with_proc_cpuinfo():
    flags: set[str] = set()
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        key, _, value = line.partition(":")
        if key.strip() == "flags":
            flags = set(value.split())
            break
    assert hardware.cpu_flags() == frozenset(flags)
    if platform.machine() in ("x86_64", "AMD64"):
        assert {"sse2", "fpu"} <= flags  # the parse found the real line
    native = bool(flags & {"avx512_bf16", "amx_bf16"})
    assert hardware.native_bf16("cpu") is native
    assert resolve_precision(smoke()).mixed_precision == ("bf16" if native else "no")  # smoke: device cpu


# ----- 8. the resolved choice is recorded and kept on resume ------------------------------------------------
@pytest.mark.parametrize("forced", [None, "other"])
def test_config_json_records_the_resolved_precision_and_resume_keeps_it(
    tiny_store, tmp_path, monkeypatch, forced, train_fresh
):
    if forced is not None:  # the choice this machine would not make, so that both branches run anywhere
        real = hardware.native_bf16("cpu")
        monkeypatch.setattr(training_setup, "native_bf16", lambda device_type: not real)
    run = tmp_path / "run"
    first = cfg(tiny_store, run, steps=4, save_every=2, eval_every=2, log_every=1, stop_at=2)
    assert first.mixed_precision == "auto"
    chosen = resolve_precision(first).mixed_precision
    assert chosen in ("bf16", "no")
    out = train_fresh(first)
    assert out["step"] == 2
    saved = json.loads((run / "config.json").read_text())
    assert saved["mixed_precision"] == chosen
    state = json.loads((run / "checkpoints/step_000002/training_state/state.json").read_text())
    assert state["config"]["mixed_precision"] == chosen  # what a resume is checked against
    text = (run / "config.json").read_text()
    other = OTHER[chosen]
    with pytest.raises(ConfigMismatch, match=rf"mixed_precision: '{chosen}' -> '{other}'") as info:
        train_fresh(dataclasses.replace(first, resume=True, stop_at=None, mixed_precision=other))
    assert str(run / "checkpoints" / "step_000002") in str(info.value)
    assert (run / "config.json").read_text() == text  # a refused resume rewrites nothing
    assert [s for s, _ in list_checkpoints(run)] == [2]
    # auto again resolves to the same choice here, and so does naming it: both resume
    train_fresh(dataclasses.replace(first, resume=True, stop_at=3))
    train_fresh(dataclasses.replace(first, resume=True, stop_at=None, mixed_precision=chosen))
    assert [s for s, _ in list_checkpoints(run)][-1] == 4
    assert json.loads((run / "config.json").read_text())["mixed_precision"] == chosen


# ----- 9. the bf16 path is deterministic ----------------------------------------------------------------------
def test_two_bf16_runs_give_bit_identical_weights_and_differ_from_float32(tiny_store, tmp_path, train_fresh):
    kw = dict(steps=4, save_every=4, eval_every=4, log_every=1, gaze=GazeConfig(prior="square", weight=0.5))
    for name, precision in (("a", "bf16"), ("b", "bf16"), ("f32", "no")):
        train_fresh(cfg(tiny_store, tmp_path / name, mixed_precision=precision, **kw))
        saved = json.loads((tmp_path / name / "config.json").read_text())
        assert saved["mixed_precision"] == precision
    for file in ("model.safetensors", OPT):  # the weights and the AdamW moments
        a, b = weights(tmp_path / "a", 4, file), weights(tmp_path / "b", 4, file)
        assert a.keys() == b.keys() and a
        for k in a:
            assert torch.equal(a[k], b[k]), (file, k)
    a, f = weights(tmp_path / "a", 4), weights(tmp_path / "f32", 4)
    assert all(v.dtype == torch.float32 for v in a.values())  # master weights stay float32 under autocast
    assert not all(torch.equal(a[k], f[k]) for k in a)  # bf16 really ran: other rounding, other weights
    metrics = [(tmp_path / n / "metrics.jsonl").read_text().splitlines() for n in ("a", "b")]
    keys = ("step", "loss", "loss/action", "loss/gaze_kl", "grad_norm")
    recs = [[[json.loads(line)[k] for k in keys] for line in m] for m in metrics]
    assert recs[0] == recs[1] and len(recs[0]) == 4


# ----- 10. fused AdamW --------------------------------------------------------------------------------------
def test_the_optimiser_is_the_fused_adamw_and_steps_like_the_loop(tiny_store, tmp_path):
    c = cfg(tiny_store, tmp_path / "run")
    policy = training_setup.build(c).policy
    assert next(policy.parameters()).device.type == "cpu"
    opt, _, _ = make_optimiser(policy, c)
    assert isinstance(opt, torch.optim.AdamW) and opt.defaults["fused"] is True
    assert all(g["fused"] is True for g in opt.param_groups)
    params = [p for g in opt.param_groups for p in g["params"]]
    assert sum(p.numel() for p in params) == sum(p.numel() for p in policy.parameters() if p.requires_grad)
    # one update equals the per-tensor AdamW's over the same groups, to float32 rounding
    skip = ("params", "fused", "foreach")
    copies = [[p.detach().clone().requires_grad_() for p in g["params"]] for g in opt.param_groups]
    loop = torch.optim.AdamW(
        [
            {**{k: v for k, v in g.items() if k not in skip}, "params": ps}
            for g, ps in zip(opt.param_groups, copies)
        ],
        foreach=False,
    )
    assert not loop.param_groups[0]["fused"] and not loop.param_groups[0]["foreach"]
    before = [p.detach().clone() for p in params]
    g = torch.Generator().manual_seed(0)
    for p, q in zip(params, (q for ps in copies for q in ps)):
        p.grad = torch.randn(p.shape, generator=g)
        q.grad = p.grad.clone()
    opt.step()
    loop.step()
    for p, q, p0 in zip(params, (q for ps in copies for q in ps), before):
        assert not torch.equal(p.detach(), p0)
        torch.testing.assert_close(p.detach(), q.detach(), rtol=1e-5, atol=1e-7)
