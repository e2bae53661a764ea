import dataclasses
import json
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from gazereg.policies import load_policy
from gazereg.training.checkpoint import latest_checkpoint, list_checkpoints
from gazereg.training.config import GazeConfig, OptimConfig, smoke
from gazereg.training.logger import read_metrics
from gazereg.training.loop import main, train

ROOT = Path(__file__).resolve().parents[2]


def cfg(store, run_dir, **kw):
    base = smoke()
    gaze = kw.pop("gaze", GazeConfig())
    optim = kw.pop("optim", base.optim)
    data = dataclasses.replace(base.data, store=Path(store.root), val_fraction=0.25)
    return dataclasses.replace(base, run_dir=Path(run_dir), data=data, gaze=gaze, optim=optim, **kw)


def params(run_dir, step):
    return load_file(str(Path(run_dir) / "checkpoints" / f"step_{step:06d}" / "model.safetensors"))


@pytest.mark.parametrize("gaze", [False, True])
def test_smoke_training_from_the_command_line(tiny_store, tmp_path, capsys, gaze):
    run = tmp_path / "run"
    args = ["--preset", "ci", "--data.store", str(tiny_store.root), "--run-dir", str(run)]
    if gaze:
        args += ["--gaze.prior", "square", "--gaze.weight", "0.5"]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["step"] == 20
    recs = read_metrics(run / "metrics.jsonl")
    assert [r["step"] for r in recs] == [5, 10, 15, 20]
    for r in recs:
        assert {"loss/action", "lr", "time/step_s", "grad_norm", "val/loss_action"} <= set(r) or r[
            "step"
        ] % 10
        assert ("loss/gaze_kl" in r) == gaze and ("gaze/weight" in r) == gaze
    if gaze:
        assert recs[-1]["gaze/weight"] == 0.5 and {
            "align_val/kl",
            "align_val/cc",
            "align_val/auc_judd",
        } <= set(recs[-1])
    resolved = json.loads((run / "config.json").read_text())
    assert resolved["policy"]["cameras"] == ["cam"] and resolved["policy"]["state_dim"] == 4
    assert [s for s, _ in list_checkpoints(run)] == [10, 20]
    ck = latest_checkpoint(run)
    policy = load_policy(ck)
    assert policy.config.head == "l1" and not any(p.suffix == ".pt" for p in ck.rglob("*"))
    with pytest.raises(FileExistsError, match="--resume"):
        main(args)


def test_gaze_weight_zero_and_gaze_disabled_reproduce_the_baseline_bit_for_bit(tiny_store, tmp_path):
    common = dict(steps=8, save_every=8, eval_every=4, log_every=1)
    train(cfg(tiny_store, tmp_path / "base", **common))
    train(cfg(tiny_store, tmp_path / "w0", gaze=GazeConfig(prior="square", weight=0.0), **common))
    train(cfg(tiny_store, tmp_path / "off", gaze=GazeConfig(prior="square", enabled=False), **common))
    train(cfg(tiny_store, tmp_path / "gaze", gaze=GazeConfig(prior="square", weight=1.0), **common))
    base = params(tmp_path / "base", 8)
    for other in ("w0", "off"):
        p = params(tmp_path / other, 8)
        assert p.keys() == base.keys() and all(torch.equal(p[k], base[k]) for k in base), other
    b_losses = [r["loss/action"] for r in read_metrics(tmp_path / "base" / "metrics.jsonl")]
    assert [r["loss/action"] for r in read_metrics(tmp_path / "w0" / "metrics.jsonl")] == b_losses
    assert "loss/gaze_kl" in read_metrics(tmp_path / "w0" / "metrics.jsonl")[0]
    assert "align_val/kl" in read_metrics(tmp_path / "off" / "metrics.jsonl")[3]  # alignment still reported
    g = params(tmp_path / "gaze", 8)
    assert g.keys() == base.keys() and all(g[k].shape == base[k].shape for k in base)  # same architecture
    assert not all(torch.equal(g[k], base[k]) for k in base)


def test_resume_continues_the_identical_trajectory(tiny_store, tmp_path):
    kw = dict(
        steps=12,
        save_every=6,
        eval_every=6,
        log_every=1,
        gaze=GazeConfig(prior="square", weight=0.5),
        optim=OptimConfig(lr=1e-3, warmup_steps=3, ema_decay=0.9),
    )
    train(cfg(tiny_store, tmp_path / "straight", **kw))
    train(cfg(tiny_store, tmp_path / "split", stop_at=6, **kw))
    assert [s for s, _ in list_checkpoints(tmp_path / "split")] == [6]
    train(cfg(tiny_store, tmp_path / "split", resume=True, **kw))
    a = read_metrics(tmp_path / "straight" / "metrics.jsonl")
    b = read_metrics(tmp_path / "split" / "metrics.jsonl")
    keys = ("step", "loss", "loss/action", "loss/gaze_kl", "lr", "grad_norm")
    assert [[r[k] for k in keys] for r in a] == [[r[k] for k in keys] for r in b]
    assert a[-1]["val/loss_action"] == b[-1]["val/loss_action"]
    pa, pb = params(tmp_path / "straight", 12), params(tmp_path / "split", 12)  # EMA weights
    assert all(torch.equal(pa[k], pb[k]) for k in pa)
    raw = "training_state/model_raw.safetensors"
    ra = load_file(str(tmp_path / "straight/checkpoints/step_000012" / raw))
    rb = load_file(str(tmp_path / "split/checkpoints/step_000012" / raw))
    assert all(torch.equal(ra[k], rb[k]) for k in ra)


def test_gaze_term_aligns_attention_and_callbacks_run(tiny_store, tmp_path):
    seen = []

    def callback(step, policy):
        assert not policy.training
        seen.append(step)
        return {"eval/dummy": float(step)}

    c = cfg(
        tiny_store,
        tmp_path / "g",
        steps=80,
        eval_every=40,
        save_every=80,
        log_every=10,
        gaze=GazeConfig(prior="square", weight=1.0),
        optim=OptimConfig(lr=2e-3, warmup_steps=10),
    )
    out = train(c, callbacks=[callback])
    assert seen == [40, 80] and out["metrics"]["eval/dummy"] == 80.0
    recs = read_metrics(tmp_path / "g" / "metrics.jsonl")
    assert recs[-1]["loss/gaze_kl"] < 0.5 * recs[0]["loss/gaze_kl"]
    assert recs[-1]["loss/action"] < recs[0]["loss/action"]


def test_flow_head_trains(tiny_store, tmp_path):
    c = cfg(
        tiny_store, tmp_path / "flow", steps=6, save_every=6, eval_every=6, gaze=GazeConfig(prior="square")
    )
    c = dataclasses.replace(c, policy=dataclasses.replace(c.policy, head="flow", flow_steps=3))
    out = train(c)
    assert out["step"] == 6 and load_policy(out["checkpoint"]).config.head == "flow"


def test_two_process_cpu_ddp(tiny_store, launch_two):
    def argv(folder):
        args = ["-m", "gazereg.training.loop", "--preset", "ci", "--data.store", str(tiny_store.root)]
        args += ["--run-dir", str(folder / "ddp"), "--gaze.prior", "square", "--steps", "6"]
        return args + ["--save-every", "6", "--eval-every", "6", "--log-every", "3"]

    r, folder = launch_two(argv, lambda folder: (folder / "ddp/checkpoints/step_000006").is_dir())
    run = folder / "ddp"
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "2 process(es)" in r.stderr
    recs = read_metrics(run / "metrics.jsonl")
    assert [x["step"] for x in recs] == [3, 6] and "loss/gaze_kl" in recs[-1]
    assert load_policy(latest_checkpoint(run)).num_parameters() > 0


def test_two_processes_log_the_gaze_term_of_one_process(tiny_store, launch_two, tmp_path, capsys):
    """Two CPU processes (DDP, 4 samples each) and one process on the same global batch of 8: the first step's
    gaze term and its logs are the same. Seed 1's first batch holds 5 samples with gaze, so the processes hold
    different numbers of them; a per-process mean averaged over the processes would log (and optimise)
    1.7684 where one process has 1.7825. Tolerance 1e-5 relative: the per-sample float32 divergences are summed
    in another order (4 + 4, rescaled, then a float64 mean over the processes, vs one sum of 8) after matmuls over
    4-row instead of 8-row batches: measured differences are about 1e-7 relative."""
    args = ["--preset", "ci", "--data.store", str(tiny_store.root), "--gaze.prior", "square", "--seed", "1"]
    args += ["--shift", "0", "--steps", "1", "--log-every", "1", "--eval-every", "1", "--save-every", "1"]
    assert main([*args, "--run-dir", str(tmp_path / "one")]) == 0
    capsys.readouterr()
    one = read_metrics(tmp_path / "one" / "metrics.jsonl")[0]
    r, folder = launch_two(
        lambda folder: ["-m", "gazereg.training.loop", *args, "--run-dir", str(folder / "ddp")],
        lambda folder: (folder / "ddp/checkpoints/step_000001").is_dir(),
    )
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "2 process(es)" in r.stderr
    two = read_metrics(folder / "ddp" / "metrics.jsonl")[0]
    assert one["step"] == two["step"] == 1
    assert one["gaze/valid_frac"] == two["gaze/valid_frac"] == 0.625  # 5 of 8: 2 + 3 or 1 + 4 per process
    for key in ("loss/gaze_kl", "gaze/patch_mass"):
        assert two[key] == pytest.approx(one[key], rel=1e-5), key
