"""Perturbations: each changes the image as intended and nothing else."""

from __future__ import annotations

import numpy as np
import pytest

from gazereg.envs.perturbations import (
    Lighting,
    Perturbation,
    SensorNoise,
    make_perturbation,
    parse_perturbation,
)


# ----- without the simulator --------------------------------------------------------------------------------
def test_gaussian_noise_statistics_and_determinism():
    img = np.full((64, 64, 3), 128, np.uint8)
    noise = SensorNoise(gaussian_std=0.1)
    a = noise.apply(img, np.random.default_rng(0))
    b = noise.apply(img, np.random.default_rng(0))
    np.testing.assert_array_equal(a, b)
    assert a.dtype == np.uint8 and a.shape == img.shape
    assert abs(a.astype(float).mean() - 128) < 1.0
    assert abs(a.astype(float).std() - 25.5) < 1.0
    np.testing.assert_array_equal(img, 128)  # the input is untouched


def test_salt_and_pepper_fraction():
    img = np.full((100, 100, 3), 128, np.uint8)
    out = SensorNoise(salt_pepper=0.1).apply(img, np.random.default_rng(1))
    changed = (out != 128).any(-1)
    assert 0.08 < changed.mean() < 0.12
    vals = out[changed]
    assert set(np.unique(vals)) <= {0, 255}
    assert 0.4 < (vals[:, 0] == 255).mean() < 0.6


def test_named_perturbations_and_composition():
    assert make_perturbation("dim", 0).is_identity
    assert make_perturbation("dim", 1.0).lighting.intensity == pytest.approx(0.25)
    assert make_perturbation("bright", 0.5).lighting.intensity == pytest.approx(1.5)
    p = parse_perturbation("dim:0.5+gaussian_noise:0.5")
    assert p.lighting.intensity == pytest.approx(0.625) and p.noise.gaussian_std == pytest.approx(0.06)
    assert p.name == "dim:0.5+gaussian_noise:0.5"
    assert parse_perturbation("").is_identity
    both = Perturbation(noise=SensorNoise(0.03)) + Perturbation(noise=SensorNoise(0.04))
    assert both.noise.gaussian_std == pytest.approx(0.05)
    assert (Lighting(color=(1, 0.5, 1)) + Lighting(color=(0.5, 1, 1))).color == (0.5, 0.5, 1)
    with pytest.raises(KeyError, match="unknown perturbation"):
        make_perturbation("fog")
    with pytest.raises(ValueError, match="severity"):
        make_perturbation("dim", 2.0)


# ----- in the simulator -------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def env(gl_backend):
    from gazereg.envs import MetaWorldEnv

    e = MetaWorldEnv(
        "pick-place-v3", cameras=("corner2",), image_size=64, gl_backend=gl_backend, max_steps=120
    )
    yield e
    e.close()


def _image(env, p, seed=0):
    obs, _ = env.reset(seed=seed, options={"perturbation": p})
    return obs["images"]["corner2"].astype(np.float64)


@pytest.mark.sim
def test_lighting_changes_brightness_in_the_expected_direction(env):
    clean = _image(env, Perturbation())
    dim, bright = _image(env, make_perturbation("dim", 1.0)), _image(env, make_perturbation("bright", 0.5))
    assert dim.mean() < clean.mean() - 20
    assert bright.mean() > clean.mean() + 5
    no_head = _image(env, make_perturbation("headlight", 1.0))
    assert no_head.mean() < clean.mean() - 10
    ambient = _image(env, make_perturbation("ambient", 1.0))
    assert ambient.mean() > clean.mean() + 5
    tint = _image(env, make_perturbation("tint", 1.0))
    ratio = lambda im: im[..., 0].mean() / im[..., 2].mean()  # noqa: E731
    assert ratio(tint) > ratio(clean) * 1.15  # warmer: more red than blue
    turned = _image(env, make_perturbation("light_direction", 1.0))
    assert np.abs(turned - clean).mean() > 1.0
    # back to clean: lighting is absolute, not cumulative
    np.testing.assert_array_equal(_image(env, Perturbation()), clean)


@pytest.mark.sim
def test_noise_is_seeded_per_episode(env):
    p = make_perturbation("gaussian_noise", 0.5)
    a, b, c = _image(env, p, seed=0), _image(env, p, seed=0), _image(env, p, seed=1)
    np.testing.assert_array_equal(a, b)
    clean0 = _image(env, Perturbation(), seed=0)
    assert np.abs(a - clean0).mean() > 3
    assert not np.array_equal(a - clean0, c - _image(env, Perturbation(), seed=1))


@pytest.mark.sim
def test_perturbations_change_nothing_but_pixels(env):
    """An expert rollout under strong lighting + noise has the same states, actions, rewards and success."""
    from gazereg.envs import Expert

    def rollout(p):
        obs, info = env.reset(seed=4, options={"perturbation": p})
        expert = Expert("pick-place-v3")
        states, actions, rewards, succ, raws = [], [], [], [], []
        for _ in range(120):
            a = expert(env.raw_obs)
            states.append(obs["state"])
            actions.append(a)
            raws.append(info["raw_obs"])
            obs, r, term, trunc, info = env.step(a)
            rewards.append(r)
            succ.append(info["success"])
            if term or trunc:
                break
        return [np.asarray(x) for x in (states, actions, rewards, succ, raws)], obs

    clean, _ = rollout(Perturbation())
    pert, obs = rollout(parse_perturbation("dim:1+tint:1+gaussian_noise:1+salt_pepper:1"))
    for x, y in zip(clean, pert):
        np.testing.assert_array_equal(x, y)
    assert clean[3][-1]  # the expert succeeded in both
    assert obs["instruction"] == "Pick up the puck and place it at the goal."
