"""GLC targets, loss, schedule, and the training loop (loss goes down, resume repeats the run)."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest
import torch

from gazereg.gaze.glc import GLC, GLCConfig
from gazereg.gaze.glc.checkpoint import load_glc
from gazereg.gaze.glc.targets import gaze_target_maps
from gazereg.training.checkpoint import latest_checkpoint
from gazereg.training.glc import GLCTrainConfig, evaluate_loss, glc_kl_loss, lr_at, train_glc
from gazereg.training.glc_data import moving_dot_clips

# a CPU-second-sized GLC: 8x64x64 clips -> 8x16x16 maps, one q-stride stage
TINY = GLCConfig(
    crop_size=64,
    embed_dim=32,
    depth=3,
    q_stride_blocks=(1,),
    decoder_heads=(2, 1),
    decoder_kv_strides=((1, 4, 4), (1, 8, 8)),
    global_embed_convs=2,
)


def test_target_maps_official_kernel():
    pts = torch.tensor([[0.5, 0.25], [0.0, 0.0], [0.3, 0.3], [1.5, 0.5], [0.5, 0.5]])
    valid = torch.tensor([True, True, False, True, True])
    maps = gaze_target_maps(pts, valid, (64, 64))
    assert maps.shape == (5, 64, 64)
    torch.testing.assert_close(maps.sum((-2, -1)), torch.ones(5))
    m = maps[0]
    assert divmod(int(m.argmax()), 64) == (16, 32)  # (round(v*h), round(u*w))
    nz = (m > 0).nonzero()
    assert nz[:, 0].min() == 16 - 9 and nz[:, 0].max() == 16 + 9  # 19 x 19 window
    assert nz[:, 1].min() == 32 - 9 and nz[:, 1].max() == 32 + 9
    d2 = torch.tensor(9.0**2)  # ratio edge/centre of the window: exp(-9^2 / (2 * 3.2^2))
    assert float(m[16, 41] / m[16, 32]) == pytest.approx(float(torch.exp(-d2 / (2 * 3.2**2))), rel=1e-5)
    corner = maps[1]  # cut to the frame and renormalised
    assert (corner > 0).sum() == 10 * 10 and corner[0, 0] == corner.max()
    uniform = torch.full((64, 64), 1 / 4096)
    torch.testing.assert_close(maps[2], uniform)  # missing gaze
    torch.testing.assert_close(maps[3], uniform)  # out of frame
    small = gaze_target_maps(pts[4:], None, (16, 16))
    assert ((small[0] > 0).sum(-1) > 0).sum() == 5  # 19 px at 64 -> 5 px at 16


def test_kl_loss_values():
    target = gaze_target_maps(torch.rand(2, 3, 2), None, (8, 8))
    logits = 2.0 * torch.log(target + 1e-30)  # softmax(logits / 2) == target
    assert float(glc_kl_loss(logits, target)) == pytest.approx(0.0, abs=1e-5)
    flat = torch.zeros(2, 1, 3, 8, 8)
    uniform = torch.full((2, 3, 8, 8), 1 / 64)
    assert float(glc_kl_loss(flat, uniform)) == pytest.approx(0.0, abs=1e-6)
    # uniform prediction vs a one-hot target: per frame sum p log p - sum p log q
    onehot = torch.zeros(1, 1, 8, 8)
    onehot[0, 0, 3, 4] = 1.0
    expected = (math.log(1 / 64) - (63 / 64) * math.log(1e-10) - (1 / 64) * math.log(1 + 1e-10)) / math.log(
        64
    )
    assert float(glc_kl_loss(torch.zeros(1, 1, 1, 8, 8), onehot)) == pytest.approx(expected, rel=1e-5)


def test_lr_schedule():
    cfg = GLCTrainConfig(steps=100, warmup_steps=10, lr=1e-4, warmup_start_lr=1e-6, min_lr=1e-6)
    assert lr_at(0, cfg) == pytest.approx(1e-6)
    assert lr_at(10, cfg) == pytest.approx(1e-4)
    assert lr_at(55, cfg) == pytest.approx((1e-4 + 1e-6) / 2)
    assert lr_at(100, cfg) == pytest.approx(1e-6)
    lrs = [lr_at(s, cfg) for s in range(101)]
    assert all(a <= b for a, b in zip(lrs[:10], lrs[1:11])) and all(
        a >= b for a, b in zip(lrs[10:], lrs[11:])
    )


@pytest.fixture(scope="module")
def dots():
    return moving_dot_clips(8, frames=8, size=64, seed=1)


class _Killed(Exception):
    pass


def _run(tmp, dots, steps, every=4, kill_at=None):
    torch.manual_seed(0)
    model = GLC(TINY)
    cfg = GLCTrainConfig(
        steps=steps, batch_size=4, lr=2e-3, warmup_steps=2, checkpoint_every=every, log_every=2
    )

    def callback(step, loss):
        if step == kill_at:
            raise _Killed

    return model, cfg, train_glc(model, dots, cfg, tmp, callback=callback)


def test_training_lowers_loss(tmp_path, dots):
    torch.manual_seed(0)
    before = evaluate_loss(GLC(TINY), dots)
    model, cfg, out = _run(tmp_path / "run", dots, steps=12)
    after = evaluate_loss(model, dots)
    assert out.step == 12 and len(out.losses) == 12
    assert after < 0.5 * before, (before, after)
    log = [json.loads(line) for line in (tmp_path / "run" / "train_log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [2, 4, 6, 8, 10, 12]
    ckpts = sorted(p.name for p in (tmp_path / "run" / "checkpoints").iterdir())
    assert ckpts == ["step_000008", "step_000012"]  # keep_last = 2
    last = tmp_path / "run" / "checkpoints" / "step_000012"
    assert out.checkpoint == last == latest_checkpoint(tmp_path / "run")
    assert sorted(p.name for p in last.iterdir()) == ["config.json", "model.safetensors", "training_state"]
    state = sorted(p.name for p in (last / "training_state").iterdir())
    assert state == ["optimizer.json", "optimizer.safetensors", "state.json"]
    assert json.loads((last / "training_state" / "state.json").read_text())["step"] == 12
    for p, q in zip(model.state_dict().values(), load_glc(last).state_dict().values()):
        assert torch.equal(p, q)  # the checkpoint folder is also a model folder


def test_resume_continues_the_same_run(tmp_path, dots):
    straight, _, _ = _run(tmp_path / "a", dots, steps=8)
    with pytest.raises(_Killed):  # dies after step 5, checkpoint of step 4 on disk
        _run(tmp_path / "b", dots, steps=8, kill_at=5)
    resumed, cfg, out = _run(tmp_path / "b", dots, steps=8)  # fresh model, picks up step 4
    assert [s for s, _ in out.losses] == [5, 6, 7, 8]
    for (name, p), q in zip(straight.named_parameters(), resumed.parameters()):
        torch.testing.assert_close(p, q, rtol=1e-4, atol=1e-5, msg=name)
    # finished: a further call does nothing
    model = GLC(TINY)
    assert train_glc(model, dots, cfg, tmp_path / "b").losses == []


def test_iterable_of_batches(tmp_path, dots):
    clips, gaze, valid = dots
    batches = [{"clips": clips[:2], "gaze": gaze[:2]}, (clips[2:4], gaze[2:4], valid[2:4])]
    model = GLC(dataclasses.replace(TINY, drop_path_rate=0.0))
    cfg = GLCTrainConfig(steps=5, batch_size=2, warmup_steps=1)
    out = train_glc(model, iter(batches), cfg, tmp_path)
    assert out.step == 2  # the iterable ran out first
