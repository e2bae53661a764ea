"""Photometric augmentation (gazereg.training.photometric; issue 37 item 3): each jitter does what it says on
frames whose answer is known, it draws only from the step's generator (reproducible, nothing drawn when off),
out-of-range strengths are refused as options, and in training it changes the run when on and nothing when off."""

import dataclasses

import pytest
import torch
from test_train import cfg, params

from gazereg.runtime.errors import UsageError
from gazereg.training.loop import train
from gazereg.training.photometric import PhotometricConfig, grey, jitter, photometric


def gen(seed=0):
    return torch.Generator().manual_seed(seed)


def frames(B=6, value=None):
    if value is not None:
        return torch.full((B, 4, 5, 3), float(value))
    return torch.rand(B, 4, 5, 3, generator=gen(7)) * 120 + 60  # 60..180: no clipping at +-30%


def test_off_is_the_batch_itself_and_draws_nothing():
    batch = {"image.cam": frames().to(torch.uint8), "state": torch.zeros(6, 2)}
    g = gen()
    out = photometric(batch, PhotometricConfig(), g)
    assert out["image.cam"] is batch["image.cam"] and out["state"] is batch["state"]
    assert torch.equal(g.get_state(), gen().get_state())


def test_brightness_scales_each_frame_by_one_factor_in_range():
    x = frames()
    y = jitter(x, PhotometricConfig(brightness=0.3), gen())
    ratio = (y / x).flatten(1)
    assert torch.allclose(ratio, ratio[:, :1].expand_as(ratio), atol=1e-5)  # one factor per frame
    assert ((ratio[:, 0] >= 0.7) & (ratio[:, 0] <= 1.3)).all() and ratio[:, 0].std() > 0.01  # frames differ
    assert jitter(frames(value=250), PhotometricConfig(brightness=0.5), gen()).max() <= 255.0  # clipped


def test_contrast_keeps_the_mean_grey_and_saturation_each_pixels_grey():
    x = frames()
    c = jitter(x, PhotometricConfig(contrast=0.3), gen())
    assert torch.allclose(grey(c).mean(dim=(1, 2, 3)), grey(x).mean(dim=(1, 2, 3)), atol=1e-3)
    assert not torch.allclose(c, x)
    s = jitter(x, PhotometricConfig(saturation=0.3), gen())
    assert torch.allclose(grey(s), grey(x), atol=1e-3) and not torch.allclose(s, x)
    grey_frames = x.mean(-1, keepdim=True).expand_as(x)  # colourless: saturation leaves it as it is
    assert torch.allclose(
        jitter(grey_frames, PhotometricConfig(saturation=0.5), gen()), grey_frames, atol=1e-3
    )


def test_the_same_generator_gives_the_same_frames_and_cameras_differ():
    aug = PhotometricConfig(brightness=0.2, contrast=0.2, saturation=0.2)
    batch = {"image.a": frames(), "image.b": frames()}
    one, two = photometric(batch, aug, gen(3)), photometric(batch, aug, gen(3))
    assert torch.equal(one["image.a"], two["image.a"]) and torch.equal(one["image.b"], two["image.b"])
    assert not torch.equal(one["image.a"], one["image.b"])  # each camera its own factors
    assert one["image.a"].dtype == torch.float32
    with pytest.raises(ValueError, match=r"image.a: photometric augmentation takes \(B, H, W, 3\) frames"):
        photometric({"image.a": torch.zeros(2, 3, 4, 4)}, aug, gen())


@pytest.mark.parametrize("field", ["brightness", "contrast", "saturation"])
def test_strengths_outside_0_to_1_are_refused_as_options(field):
    with pytest.raises(UsageError, match=rf"--photometric.{field} must be a finite number in \[0, 1\)"):
        PhotometricConfig(**{field: 1.0})
    with pytest.raises(UsageError, match=rf"--photometric.{field}"):
        PhotometricConfig(**{field: -0.1})


def test_in_training_it_changes_the_run_when_on_and_nothing_when_off(tiny_store, tmp_path):
    common = dict(steps=4, save_every=4, eval_every=4, log_every=1)
    base = cfg(tiny_store, tmp_path / "base", **common)
    train(base)
    train(dataclasses.replace(base, run_dir=tmp_path / "off", photometric=PhotometricConfig()))
    train(dataclasses.replace(base, run_dir=tmp_path / "on", photometric=PhotometricConfig(brightness=0.4)))
    a, off, on = params(tmp_path / "base", 4), params(tmp_path / "off", 4), params(tmp_path / "on", 4)
    assert all(torch.equal(a[k], off[k]) for k in a)
    assert not all(torch.equal(a[k], on[k]) for k in a)
