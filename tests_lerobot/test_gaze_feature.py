"""Priors as a LeRobot feature: `gazereg import write-gaze` writes gaze.<camera>.heatmap / .valid into a new
data set version; the real `LeRobotDataset` loads them, the plugin turns the heatmap into a distribution over
SmolVLA's image tokens (through `resize_with_pad`), the flag masks it, and lerobot-train trains on it."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest
import torch

from conftest import FIXTURE, make_config

HEAT, VALID = "gaze.front.heatmap", "gaze.front.valid"


@pytest.fixture(scope="module")
def gaze_version(tmp_path_factory, dataset_root):
    """(store, new data set root): the fixture's episodes 0 and 1 imported, `recorded` priors (16x16, two
    frames aggregated), written into a new version; episode 2 has no prior (valid = false)."""
    from gazereg.aggregation import AggregationConfig
    from gazereg.data.formats.lerobot_v3 import LeRobotImportConfig, import_lerobot
    from gazereg.data.formats.lerobot_v3.gaze_feature import write_gaze_dataset
    from gazereg.data.store import EpisodeStore
    from gazereg.gaze.priors import PriorsConfig, make_priors

    tmp = tmp_path_factory.mktemp("gaze_feature")
    store_dir = tmp / "store"
    import_lerobot(LeRobotImportConfig(root=dataset_root, out=store_dir, episodes=(0, 1), progress=False))
    agg = AggregationConfig(past=1, future=0)
    make_priors(
        PriorsConfig(store=store_dir, source="recorded", camera="front", size=(16, 16), aggregation=agg),
        progress=False,
    )
    write_gaze_dataset(store_dir, "recorded", dataset_root, tmp / "v2")
    return EpisodeStore(store_dir), tmp / "v2"


@pytest.fixture(scope="module")
def gaze_dataset(gaze_version):
    from lerobot.datasets import LeRobotDataset

    return LeRobotDataset(
        "local/lerobot_v3_tiny_gaze",
        root=gaze_version[1],
        delta_timestamps={"action": [i / 10 for i in range(5)]},
        video_backend="pyav",
    )


def test_lerobot_dataset_loads_the_gaze_feature(gaze_version, gaze_dataset):
    store, _ = gaze_version
    ds = gaze_dataset
    assert ds.meta.features[HEAT]["shape"] == (16, 16) and ds.meta.features[VALID]["dtype"] == "bool"
    assert ds.meta.stats[HEAT]["mean"].shape == (16, 16) and ds.meta.stats[VALID]["count"].tolist() == [66]
    assert ds.num_frames == 66 and ds.num_episodes == 3
    prior, ok = store.read_prior("recorded", 1)
    sample = ds[20 + 5]  # episode 1, frame 5
    assert int(sample["episode_index"]) == 1 and int(sample["frame_index"]) == 5
    assert sample[HEAT].shape == (16, 16) and sample[HEAT].dtype == torch.float32
    torch.testing.assert_close(sample[HEAT], torch.from_numpy(prior[5]), rtol=0, atol=1e-7)
    assert sample[VALID].dtype == torch.bool and bool(sample[VALID]) == bool(ok[5]) is True
    assert sample["observation.images.front"].shape == (3, 64, 64)  # videos still decode
    last = ds[65]  # episode 2: no prior in the store
    assert not bool(last[VALID]) and float(last[HEAT].abs().sum()) == 0.0


def _reference_tokens(heat: torch.Tensor, input_hw: tuple[int, int], token_px: int) -> torch.Tensor:
    """What SmolVLA sees of a (B, h, w) heatmap over a 64x64 frame: spread over the frame's pixels, put through
    lerobot's own resize_with_pad, summed over each token's pixel block, normalised -> (B, n_tokens)."""
    from lerobot.policies.common.vla_utils import resize_with_pad

    B, h, w = heat.shape
    density = heat.repeat_interleave(64 // h, 1).repeat_interleave(64 // w, 2)[:, None]
    img = resize_with_pad(density.float(), *input_hw, pad_value=0.0)[:, 0]
    gh, gw = input_hw[0] // token_px, input_hw[1] // token_px
    tokens = img.reshape(B, gh, token_px, gw, token_px).sum((2, 4)).flatten(1)
    return tokens / tokens.sum(-1, keepdim=True)


def test_heatmap_becomes_a_token_distribution_through_resize_with_pad(gaze_dataset):
    from lerobot_policy_gazereg.gaze_targets import gaze_distribution, gaze_valid_flag, smolvla_geometry

    batch = torch.utils.data.default_collate([gaze_dataset[i] for i in (3, 30, 50, 60)])
    assert batch[HEAT].shape == (4, 16, 16) and batch[VALID].tolist() == [True, True, False, False]
    # the 64x64 frame into a 32x64 (h, w) input: resized to 32x32, padded on the left (SmolVLA's convention)
    geom, flip = smolvla_geometry((64, 64), (64, 32), patch_size=4, pixel_shuffle=2)  # 8-px tokens, 4x8
    assert flip and geom.grid_hw == (4, 8)
    flag = gaze_valid_flag(batch, HEAT)
    dist, ok = gaze_distribution(batch[HEAT], geom, flip, 0.05, (64, 64), eps=0.0, valid=flag)
    assert ok.tolist() == [True, True, False, False]
    ref = _reference_tokens(batch[HEAT][:2], (32, 64), token_px=8)
    torch.testing.assert_close(
        dist[:2], ref, rtol=0, atol=1e-6
    )  # a 2x bilinear shrink of cells = area pooling
    assert dist[:2].reshape(2, 4, 8)[:, :, :4].sum() < 1e-6  # the left padding gets nothing
    assert torch.equal(dist[2:], torch.full((2, 32), 1 / 32))  # invalid frames: uniform, masked out
    # the flag masks a frame even when its heatmap has mass
    flag = torch.tensor([True, False, False, False])
    _, ok2 = gaze_distribution(batch[HEAT], geom, flip, 0.05, (64, 64), valid=flag)
    assert ok2.tolist() == [True, False, False, False]
    assert gaze_valid_flag(batch, "gaze.point") is None and gaze_valid_flag({}, HEAT) is None


def test_policy_trains_on_the_heatmap_column(tiny_vlm, gaze_dataset):
    """The gaze policy's training forward with gaze_key = the heatmap feature: a finite gaze term."""
    from lerobot.policies import make_policy, make_pre_post_processors

    torch.manual_seed(0)
    cfg = make_config(tiny_vlm, gaze_key=HEAT)
    policy = make_policy(cfg, ds_meta=gaze_dataset.meta)
    pre, _ = make_pre_post_processors(cfg, dataset_stats=gaze_dataset.meta.stats)
    batch = pre(torch.utils.data.default_collate([gaze_dataset[i] for i in (0, 5, 25, 40)]))
    assert batch[HEAT].shape == (4, 16, 16)
    policy.train()
    loss, info = policy.forward(batch)
    assert torch.isfinite(loss) and math.isfinite(info["loss/gaze_kl"]) and info["loss/gaze_kl"] > 0
    assert info["gaze/valid_frac"] == 1.0


def test_lerobot_train_on_the_new_version(tmp_path, gaze_version, tiny_vlm):
    from test_smolvla_gaze import _lerobot_train

    r = _lerobot_train(tmp_path, gaze_version[1], tiny_vlm, 2, f"--policy.gaze_key={HEAT}")
    log = r.stdout + r.stderr
    assert r.returncode == 0, log[-4000:]
    kls = [float(x) for x in re.findall(r"loss/gaze_kl:([-0-9.naif]+)", log)]
    assert len(kls) == 2 and all(math.isfinite(k) and k > 0 for k in kls), log[-3000:]
    assert Path(FIXTURE / "meta" / "info.json").read_text().count(HEAT) == 0  # the source is untouched
