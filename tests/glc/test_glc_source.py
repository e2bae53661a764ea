"""The `glc` gaze source: clip construction, output distributions, the average mode, checkpoints."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from gazereg.data.store import EpisodeStore
from gazereg.gaze.glc.checkpoint import save_glc
from gazereg.gaze.glc.data import (
    average_anchors,
    clip_indices,
    crop_box,
    normalize,
    preprocess_frames,
    synthetic_gaze_episode,
)
from gazereg.gaze.glc.model import frame_softmax
from gazereg.gaze.priors import PriorsConfig, make_priors
from gazereg.gaze.sources import make_gaze_source
from gazereg.gaze.sources.glc import GLCGaze, GLCParams, to_frame


@pytest.fixture(scope="module")
def source():
    return make_gaze_source("glc", checkpoint="random", config="small", stride=2, mode="centre")


@pytest.fixture(scope="module")
def episode():
    return synthetic_gaze_episode(length=11, size=48, camera="cam", seed=3)


def _clip_maps(src: GLCGaze, frames: np.ndarray, rows: np.ndarray) -> torch.Tensor:
    """The model's maps for clips given by frame-index rows, computed directly: (N, 8, h, w)."""
    x = normalize(preprocess_frames(frames, src.cfg.crop_size))  # (T, 3, S, S)
    clips = x[torch.from_numpy(rows)].permute(0, 2, 1, 3, 4)
    with torch.inference_mode():
        return frame_softmax(src.model(clips), src.temperature)


def test_clip_indices_centre_position_and_edge_repetition():
    idx = clip_indices(10, [0, 5, 9], num_frames=8, stride=2)
    assert idx.shape == (3, 8)
    assert idx[:, 4].tolist() == [0, 5, 9]  # the anchor at the centre position
    assert idx[1].tolist() == [0, 0, 1, 3, 5, 7, 9, 9]  # offsets (-4..3)*2, clamped
    assert idx[0].tolist() == [0, 0, 0, 0, 0, 2, 4, 6]  # start padded by repeating frame 0
    assert idx[2].tolist() == [1, 3, 5, 7, 9, 9, 9, 9]  # end padded by repeating the last frame
    raw = clip_indices(10, [0], 8, 2, clamp=False)[0]
    assert raw.tolist() == [-8, -6, -4, -2, 0, 2, 4, 6]


@pytest.mark.parametrize(
    "T,stride,hop", [(1, 1, 4), (7, 1, 4), (23, 2, 4), (40, 3, 2), (30, 2, 8), (13, 1, 1)]
)
def test_average_anchors_cover_every_frame(T, stride, hop):
    anchors = average_anchors(T, 8, stride, hop)
    raw = clip_indices(T, anchors, 8, stride, clamp=False)
    counts = np.bincount(raw[(raw >= 0) & (raw < T)], minlength=T)
    assert (counts >= 1).all() and counts.max() <= 8 // hop + 1
    # away from the edges every frame is predicted by exactly 8 / hop clips
    assert (counts[4 * stride : max(4 * stride, T - 8 * stride)] == 8 // hop).all()


def test_source_centre_mode_gives_distributions_from_the_centre_clip(source, episode):
    heat, valid = source(episode, "cam", (16, 20))
    assert heat.shape == (11, 16, 20) and heat.dtype == np.float32 and valid.all()
    assert (heat >= 0).all() and np.allclose(heat.sum((1, 2)), 1, atol=1e-5)
    # frame t's map is the map at position 4 of the clip centred on t, resized by area (24 -> 16x20 shrinks)
    frames = episode.frames["cam"]
    rows = clip_indices(11, [0, 6, 10], 8, 2)
    direct = _clip_maps(source, frames, rows)[:, 4]
    expect = F.interpolate(direct[:, None], size=(16, 20), mode="area")[:, 0]
    expect = expect / expect.sum((1, 2), keepdim=True)
    np.testing.assert_allclose(heat[[0, 6, 10]], expect.numpy(), atol=1e-6)
    # the clips really are centred: compute them all and compare the model-resolution maps
    maps, count = source.predict(frames)
    assert count.tolist() == [1.0] * 11
    np.testing.assert_allclose(maps[[0, 6, 10]].numpy(), direct.numpy(), atol=1e-6)


def test_average_mode_is_the_mean_of_overlapping_clip_maps(source, episode):
    src = GLCGaze(GLCParams(Path("random"), "small", stride=2, mode="average", hop=2, batch_size=3))
    src.model.load_state_dict(source.model.state_dict())
    frames = episode.frames["cam"]
    T = frames.shape[0]
    maps, count = src.predict(frames)
    anchors = average_anchors(T, 8, 2, 2)
    raw = clip_indices(T, anchors, 8, 2, clamp=False)
    direct = _clip_maps(src, frames, np.clip(raw, 0, T - 1))  # (N, 8, h, w)
    for t in range(T):
        pos = np.argwhere(raw == t)  # (clip, position) pairs that predict frame t (padding excluded)
        assert len(pos) == count[t] >= 1
        expect = torch.stack([direct[c, k] for c, k in pos]).mean(0)
        np.testing.assert_allclose(maps[t].numpy(), expect.numpy(), atol=1e-6)
    heat, valid = src(episode, "cam", (24, 24))
    assert valid.all() and np.allclose(heat.sum((1, 2)), 1, atol=1e-5)
    assert len(src.plan(T)[0]) < T  # fewer clips than frames: the efficient mode


def test_non_square_frames_put_the_crop_back_into_the_frame():
    maps = torch.full((2, 24, 24), 1.0 / 576)
    out = to_frame(maps, (48, 96), 96, (12, 24))  # 48x96 -> resized 96x192, crop columns 48..144
    u0, v0, u1, v1 = crop_box(48, 96, 96)
    assert (u0, v0, u1, v1) == (0.25, 0.0, 0.75, 1.0)
    assert out.shape == (2, 12, 24)
    assert torch.all(out[:, :, :6] == 0) and torch.all(out[:, :, 18:] == 0) and torch.all(out[:, :, 6:18] > 0)
    ep = synthetic_gaze_episode(length=3, size=48, camera="cam")
    ep.frames["cam"] = np.ascontiguousarray(np.concatenate([ep.frames["cam"]] * 2, axis=2))  # 48 x 96
    heat, valid = make_gaze_source("glc", checkpoint="random", config="small", mode="centre")(
        ep, "cam", (12, 24)
    )
    assert valid.all() and np.allclose(heat.sum((1, 2)), 1, atol=1e-5) and (heat[:, :, :6] == 0).all()


def test_describe_records_random_weights_and_round_trips_json(source):
    d = source.describe()
    assert (
        d["checkpoint"] == "random" and d["config"] == "small" and d["mode"] == "centre" and d["stride"] == 2
    )
    assert json.loads(json.dumps(d)) == d


def test_missing_or_bad_checkpoint_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="needs a checkpoint"):
        make_gaze_source("glc")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        make_gaze_source("glc", checkpoint=str(tmp_path / "nope"))
    with pytest.raises(FileNotFoundError, match="not a GLC checkpoint folder"):
        make_gaze_source("glc", checkpoint=str(tmp_path))
    with pytest.raises(ValueError, match="mode"):
        make_gaze_source("glc", checkpoint="random", config="small", mode="middle")


def test_folder_checkpoint_and_priors_pipeline(tmp_path, source):
    folder = save_glc(source.model, source.cfg, tmp_path / "glc")
    store = EpisodeStore(tmp_path / "store", create=True)
    for k in range(2):
        store.write(synthetic_gaze_episode(length=6 + k, size=32, camera="cam", seed=k))
    src = make_gaze_source("glc", checkpoint=str(folder), stride=1, mode="centre")
    assert src.describe()["checkpoint_sha256"] and src.describe()["config"] == "small"
    ep = store.read(0)
    a, _ = src(ep, "cam", (8, 8))
    source_same = GLCGaze(GLCParams(Path("random"), "small", stride=1, mode="centre"))
    source_same.model.load_state_dict(source.model.state_dict())
    np.testing.assert_allclose(a, source_same(ep, "cam", (8, 8))[0], atol=1e-6)
    params = GLCParams(checkpoint=folder, stride=1, mode="centre")
    cfg = PriorsConfig(store=store.root, source=params, camera="cam", size=(8, 8))
    assert make_priors(cfg, progress=False) == "glc"
    heat, valid = store.read_prior("glc", 1)
    assert heat.shape == (7, 8, 8) and valid.all()
    assert make_priors(cfg, progress=False) == "glc"  # resumes: the stored record equals describe()
    assert store.prior_info("glc")["source"]["checkpoint"] == str(folder.resolve())
