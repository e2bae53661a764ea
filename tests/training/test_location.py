"""The location control (`--gaze.target features`, gazereg.training.location): the gaze target predicted by a
training-only head from image-token features instead of read from the policy's attention."""

import contextlib
import dataclasses
import json
import math
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from gazereg.attention.probe import AttentionProbe
from gazereg.cli import main as cli_main
from gazereg.losses import gaze_loss
from gazereg.policies import load_policy
from gazereg.runtime.config import ConfigMismatch
from gazereg.runtime.errors import UsageError
from gazereg.training import loop
from gazereg.training.checkpoint import list_checkpoints, read_checkpoint
from gazereg.training.config import GazeConfig, OptimConfig, smoke
from gazereg.training.location import HEAD_NAME, select_tokens
from gazereg.training.logger import read_metrics
from gazereg.training.loop import train
from gazereg.training.schedule import step_generator
from gazereg.training.setup import setup

HEAD_FILE = f"training_state/aux_{HEAD_NAME}.safetensors"
ROOT = Path(__file__).resolve().parents[2]


def cfg(store, run_dir, **kw):
    base = smoke()
    data = dataclasses.replace(base.data, store=Path(store.root), val_fraction=0.25)
    return dataclasses.replace(base, run_dir=Path(run_dir), data=data, **kw)


def gaze(target="attention", weight=0.5, **kw):
    return GazeConfig(prior="square", weight=weight, target=target, **kw)


# ----- the option -------------------------------------------------------------------------------------------
def test_a_bad_target_exits_2_with_one_line_naming_the_option(tiny_store, tmp_path, capsys):
    run = tmp_path / "run"
    argv = ["train", "--preset", "ci", "--data.store", str(tiny_store.root), "--run-dir", str(run)]
    assert cli_main([*argv, "--gaze.target", "heads"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["gazereg train: error: --gaze.target must be one of attention, features, got 'heads'"]
    assert not run.exists()
    with pytest.raises(UsageError, match="--gaze.target must be one of attention, features, got 'x'"):
        GazeConfig(target="x")


def test_features_from_the_command_line_record_the_mode_and_log_both_kls(tiny_store, tmp_path, capsys):
    run = tmp_path / "run"
    args = ["--preset", "ci", "--data.store", str(tiny_store.root), "--run-dir", str(run)]
    assert loop.main([*args, "--gaze.prior", "square", "--gaze.target", "features"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["step"] == 20
    assert json.loads((run / "config.json").read_text())["gaze"]["target"] == "features"
    recs = read_metrics(run / "metrics.jsonl")
    assert all({"loss/location_kl", "loss/gaze_kl", "gaze/patch_mass"} <= set(r) for r in recs)
    assert {"val/location_kl", "val/gaze_kl", "align_val/kl"} <= set(recs[-1])
    assert all(math.isfinite(r["loss"]) and math.isfinite(r["loss/location_kl"]) for r in recs)
    ck = run / "checkpoints" / "step_000020"
    assert (ck / HEAD_FILE).exists()
    # the saved policy is any policy: no head in it, and it acts
    weights = load_file(str(ck / "model.safetensors"))
    assert not any("score" in k or HEAD_NAME in k for k in weights)
    policy = load_policy(ck)
    assert set(policy.state_dict()) == set(weights)
    obs = {"state": torch.zeros(4).numpy(), "cam": torch.zeros(48, 48, 3, dtype=torch.uint8).numpy()}
    assert policy.select_action(obs, "reach the bright square").shape == (4,)


# ----- the default mode is the code it was --------------------------------------------------------------
def reference_step(run, step, batch):
    """`loop.step` as it was before the gaze.target option (commit 43d6ba4); returns terms, lr, weight."""
    cfg, acc = run.cfg, run.acc
    batch = {k: v.to(acc.device, non_blocking=True) for k, v in batch.items()}
    gen = step_generator(cfg.seed, step, acc.process_index, acc.device)
    gaze_on = run.gaze_spec is not None
    w = run.gaze_weight(step) if gaze_on else 0.0
    probe_ctx = (
        AttentionProbe(run.model, run.gaze_spec, adapter="tap") if gaze_on else contextlib.nullcontext()
    )
    with probe_ctx as probe, run.autocast():
        loss, _ = run.model(batch, generator=gen, shift=cfg.shift)
    terms = {"loss/action": float(loss.detach())}
    if probe is not None:
        kl, ginfo = gaze_loss(
            batch["gaze"],
            probe.distribution(),
            batch["gaze_valid"],
            cfg.gaze.divergence,
            cfg.gaze.loss_eps,
            gaze_grid=run.built.gaze_grid,
            attention_grid=run.built.attention_grid,
        )
        if w > 0:  # weight 0 logs the KL but leaves the graph (and so the update) exactly the baseline's
            loss = loss + w * kl
        terms.update(
            {"loss/gaze_kl": float(kl.detach()), "gaze/patch_mass": float(probe.patch_mass().mean()), **ginfo}
        )
    if not torch.isfinite(loss):
        raise FloatingPointError(f"non-finite loss at step {step}: {terms}")
    run.opt.zero_grad(set_to_none=True)
    acc.backward(loss)
    clip = cfg.optim.grad_clip
    grad_norm = acc.clip_grad_norm_(run.model.parameters(), clip) if clip > 0 else None
    run.opt.step()
    lr = run.sched.get_last_lr()[0]
    run.sched.step()
    if run.ema is not None:
        run.ema.update(run.policy)
    terms["loss"] = float(loss.detach())
    if grad_norm is not None:
        terms["grad_norm"] = float(grad_norm)
    return terms, lr, w


def test_the_attention_mode_step_is_bit_identical_to_the_previous_code(tiny_store, tmp_path):
    runs = {name: setup(cfg(tiny_store, tmp_path / name, gaze=gaze())) for name in ("new", "old")}
    assert runs["new"].location_head is None and runs["new"].cfg.gaze.target == "attention"
    for i, batch in zip(range(3), runs["new"].loader):
        new = loop.step(runs["new"], i, batch)
        old_terms, old_lr, old_w = reference_step(runs["old"], i, batch)
        assert new.terms == old_terms and (new.lr, new.gaze_weight) == (old_lr, old_w)
        assert "loss/location_kl" not in new.terms
    a, b = runs["new"].policy.state_dict(), runs["old"].policy.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_features_with_weight_zero_reproduce_the_baseline_bit_for_bit(tiny_store, tmp_path):
    common = dict(steps=6, save_every=6, eval_every=3, log_every=1)
    train(cfg(tiny_store, tmp_path / "base", **common))
    train(cfg(tiny_store, tmp_path / "w0", gaze=gaze("features", 0.0), **common))
    a = load_file(str(tmp_path / "base/checkpoints/step_000006/model.safetensors"))
    b = load_file(str(tmp_path / "w0/checkpoints/step_000006/model.safetensors"))
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert "loss/location_kl" in read_metrics(tmp_path / "w0" / "metrics.jsonl")[0]


# ----- what the location term reaches -----------------------------------------------------------------------
def gradients_of_the_gaze_term_alone(store, run_dir, target):
    """The policy's and head's gradients after one step whose action loss is multiplied by 0."""
    run = setup(cfg(store, run_dir, gaze=gaze(target, 1.0)))
    forward = run.model.forward

    def gaze_term_only(*args, **kw):
        loss, info = forward(*args, **kw)
        return loss * 0, info

    run.model.forward = gaze_term_only
    out = loop.step(run, 0, next(iter(run.loader)))
    grads = {k: p.grad.clone() for k, p in run.policy.named_parameters() if p.grad is not None}
    return run, out, grads


def test_the_location_term_reaches_no_action_query_parameter_and_not_attention_alike(tiny_store, tmp_path):
    att_run, att_out, att = gradients_of_the_gaze_term_alone(tiny_store, tmp_path / "a", "attention")
    loc_run, loc_out, loc = gradients_of_the_gaze_term_alone(tiny_store, tmp_path / "f", "features")
    assert loc_out.terms["loss"] == pytest.approx(loc_out.terms["loss/location_kl"])
    assert att_out.terms["loss"] == pytest.approx(att_out.terms["loss/gaze_kl"])
    # the probed attention is the action queries': the attention term moves their embeddings
    assert att["action_pos"].abs().sum() > 0
    # the image tokens never see the action queries: the location term cannot reach that side at all
    for name in ("action_pos", "action_out.weight", "action_out.bias", "norm.weight", "norm.bias"):
        assert name not in loc or not loc[name].any(), name
    assert loc["stem.net.0.weight"].abs().sum() > 0  # it does reach the shared trunk ...
    assert loc_run.location_head.score.weight.grad.abs().sum() > 0  # ... and trains the head
    last = loc_run.policy.config.depth - 1
    qkv = f"blocks.{last}.attn.qkv.weight"
    assert not torch.allclose(att[qkv], loc[qkv])  # the attention logits' parameters get another gradient


def test_the_head_reads_the_last_probed_layers_patch_tokens():
    x = torch.arange(2 * 5 * 3, dtype=torch.float32).reshape(2, 5, 3)
    assert torch.equal(select_tokens(x, slice(1, 3)), x[:, 1:3])
    assert torch.equal(select_tokens(x, [4, 0]), x[:, [4, 0]])
    per_sample = select_tokens(x, torch.tensor([[0, 1], [3, 4]]))
    assert torch.equal(per_sample, torch.stack([x[0, [0, 1]], x[1, [3, 4]]]))


# ----- training, saving, resuming ---------------------------------------------------------------------------
def test_the_head_overfits_the_gaze_on_a_tiny_store(tiny_store, tmp_path):
    c = cfg(
        tiny_store,
        tmp_path / "f",
        steps=60,
        eval_every=60,
        save_every=60,
        log_every=10,
        gaze=gaze("features", 1.0),
        optim=OptimConfig(lr=2e-3, warmup_steps=10),
    )
    train(c)
    recs = read_metrics(tmp_path / "f" / "metrics.jsonl")
    assert all(math.isfinite(r["loss"]) for r in recs)
    assert recs[-1]["loss/location_kl"] < 0.25 * recs[0]["loss/location_kl"]
    assert recs[-1]["val/location_kl"] < 0.25 * recs[0]["loss/location_kl"]
    assert recs[-1]["loss/action"] < recs[0]["loss/action"]


def test_the_head_is_saved_and_a_resume_restores_it(tiny_store, tmp_path):
    kw = dict(steps=8, save_every=4, eval_every=4, log_every=1, gaze=gaze("features", 1.0))
    kw["optim"] = OptimConfig(lr=2e-3, warmup_steps=2, ema_decay=0.9)
    train(cfg(tiny_store, tmp_path / "straight", **kw))
    train(cfg(tiny_store, tmp_path / "split", stop_at=4, **kw))
    saved = read_checkpoint(tmp_path / "split" / "checkpoints" / "step_000004").aux[HEAD_NAME]
    fresh = setup(cfg(tiny_store, tmp_path / "fresh", **kw)).location_head.state_dict()
    assert saved.keys() == fresh.keys() and not torch.equal(saved["score.weight"], fresh["score.weight"])
    train(cfg(tiny_store, tmp_path / "split", resume=True, **kw))
    a = read_metrics(tmp_path / "straight" / "metrics.jsonl")
    b = read_metrics(tmp_path / "split" / "metrics.jsonl")
    keys = ("step", "loss", "loss/location_kl", "loss/gaze_kl", "grad_norm", "val/location_kl")
    assert [[r.get(k) for k in keys] for r in a] == [[r.get(k) for k in keys] for r in b]
    ha = load_file(str(tmp_path / "straight/checkpoints/step_000008" / HEAD_FILE))
    hb = load_file(str(tmp_path / "split/checkpoints/step_000008" / HEAD_FILE))
    assert torch.equal(ha["score.weight"], hb["score.weight"])


def test_resume_refuses_another_target_and_accepts_a_checkpoint_from_before_the_option(tiny_store, tmp_path):
    run = tmp_path / "run"
    first = cfg(tiny_store, run, steps=8, save_every=4, eval_every=4, stop_at=4, gaze=gaze())
    train(first)
    with pytest.raises(ConfigMismatch, match=r"gaze\.target: 'attention' -> 'features'"):
        train(dataclasses.replace(first, resume=True, stop_at=None, gaze=gaze("features")))
    assert [s for s, _ in list_checkpoints(run)] == [4]
    state = run / "checkpoints" / "step_000004" / "training_state" / "state.json"
    saved = json.loads(state.read_text())
    del saved["config"]["gaze"]["target"]  # a checkpoint written before gaze.target existed
    state.write_text(json.dumps(saved))
    with pytest.raises(ConfigMismatch, match=r"gaze\.target: 'attention' -> 'features'"):
        train(dataclasses.replace(first, resume=True, stop_at=None, gaze=gaze("features")))
    assert train(dataclasses.replace(first, resume=True, stop_at=None))["step"] == 8


DDP_SCRIPT = """
import dataclasses, sys
from pathlib import Path
from gazereg.training import loop
from gazereg.training.config import GazeConfig, smoke
from gazereg.training.setup import setup

base = smoke()
data = dataclasses.replace(base.data, store=Path(sys.argv[1]))
gaze = GazeConfig(prior="square", weight=1.0, target="features")
run = setup(dataclasses.replace(base, run_dir=Path(sys.argv[2]), data=data, gaze=gaze, mixed_precision="no"))
for i, batch in zip(range(3), run.loader):
    loop.step(run, i, batch)
head = run.location_head.score.weight.double().sum().item()
Path(sys.argv[2]).with_name(f"head{run.acc.process_index}").write_text(repr(head))  # ranks' prints interleave
run.acc.end_training()
"""


def test_two_processes_average_the_heads_gradients(tiny_store, tmp_path, launch_two):
    script = tmp_path / "ddp_head.py"
    script.write_text(DDP_SCRIPT)
    r, folder = launch_two(
        lambda folder: [str(script), str(tiny_store.root), str(folder / "run")],
        lambda folder: (folder / "head0").is_file() and (folder / "head1").is_file(),
    )
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    heads = [(folder / f"head{rank}").read_text() for rank in (0, 1)]
    assert heads[0] == heads[1]  # the ranks' heads stay the same
