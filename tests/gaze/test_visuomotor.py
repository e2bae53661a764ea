"""The visuomotor gaze source: eyes on the object before the grasp, on the goal after it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gazereg.data.store import Episode
from gazereg.gaze.sources import available_gaze_sources, make_gaze_source
from gazereg.runtime.errors import UsageError

CAM = "cam"


def synthetic_episode(
    T: int = 60, contact_at: int = 30, task: str = "pick-place-v3", seed: int = 0
) -> Episode:
    """The hand reaches the object at `contact_at`, then carries it to the goal by the last frame.

    World x maps linearly to image u (v fixed per point), so projected and world positions agree."""
    t = np.arange(T, dtype=np.float64)
    obj0, goal = np.array([0.0, 0.0, 0.0]), np.array([0.4, 0.0, 0.0])
    start = np.array([-0.4, 0.0, 0.2])
    a = np.clip(t / contact_at, 0, 1)[:, None]
    hand = (1 - a) * start + a * obj0
    b = np.clip((t - contact_at) / (T - 1 - contact_at), 0, 1)[:, None]
    hand = np.where(t[:, None] >= contact_at, (1 - b) * obj0 + b * goal, hand)
    obj = np.where(t[:, None] >= contact_at, hand, obj0)

    def uv(p, v):
        return np.stack([0.5 + p[:, 0], np.full(len(p), v)], 1).astype(np.float32)

    success = np.zeros(T, bool)
    success[-1] = True
    contact = t >= contact_at
    return Episode(
        task=task,
        instruction="Pick up the puck and place it at the goal.",
        frames={CAM: np.zeros((T, 32, 32, 3), np.uint8)},
        state=np.zeros((T, 4), np.float32),
        action=np.zeros((T, 4), np.float32),
        extras={
            "obj_pos": obj.astype(np.float32),
            "goal_pos": np.tile(goal, (T, 1)).astype(np.float32),
            "hand_pos": hand.astype(np.float32),
            f"obj_uv.{CAM}": uv(obj, 0.6),
            f"goal_uv.{CAM}": uv(np.tile(goal, (T, 1)), 0.3),
            f"hand_uv.{CAM}": uv(hand, 0.5),
            "contact": contact,
            "grasp": contact,
            "success": success,
        },
        meta={"fps": 80.0, "seed": seed},
        index=seed,
    )


def test_registered():
    assert "visuomotor" in available_gaze_sources()
    src = make_gaze_source("visuomotor", lead_time_s=0.5)
    assert src.name == "visuomotor" and src.describe()["lead_time_s"] == 0.5
    with pytest.raises(UsageError, match="visuomotor"):
        make_gaze_source("visuomotor", lead=1)


def test_object_before_contact_goal_after():
    ep = synthetic_episode()
    src = make_gaze_source("visuomotor", jitter=0.0, dwell_s=0.05, saccade_s=0.04)
    tr = src.trace(ep, CAM)
    # contact at 30; the puck comes within arrive_radius (3 cm) of the goal at 57 (success would be at 60)
    assert tr.targets == ("obj", "goal") and tr.arrivals == (30, 57)
    assert make_gaze_source(replace(src.params, arrive_radius=0.0)).trace(ep, CAM).arrivals == (30, 60)
    s = tr.switches[1]
    assert s == 30 + 4  # dwell: 0.05 s at 80 fps
    np.testing.assert_allclose(tr.uv[:s], ep.extras[f"obj_uv.{CAM}"][:s], atol=1e-6)
    after = s + 3  # after the saccade (0.04 s: 3 frames)
    np.testing.assert_allclose(tr.uv[after:], ep.extras[f"goal_uv.{CAM}"][after:], atol=1e-6)
    # during the saccade the point moves monotonically from the object to the goal
    u = tr.uv[s - 1 : after + 1, 0]
    v = tr.uv[s - 1 : after + 1, 1]
    assert (np.diff(v) < 0).all() and (np.diff(u) >= 0).all()
    assert (tr.target[:s] == 0).all() and (tr.target[s:] == 1).all()


def test_eyes_lead_the_hand_on_long_transports():
    ep = synthetic_episode(T=200, contact_at=20)  # the transport takes 180 frames (2.25 s)
    tr = make_gaze_source("visuomotor", jitter=0.0, lead_time_s=1.0, arrive_radius=0.0).trace(ep, CAM)
    assert (
        tr.arrivals == (20, 200) and tr.switches[1] == 200 - 80
    )  # on the goal 1 s (80 frames) before the object arrives there
    tr = make_gaze_source("visuomotor", jitter=0.0, lead_time_s=5.0, dwell_s=0.0).trace(ep, CAM)
    assert tr.switches[1] == 20  # a long lead: the saccade follows the grasp at once


def test_reach_looks_at_the_goal_and_unreached_targets_are_held():
    ep = synthetic_episode(task="reach-v3")
    tr = make_gaze_source("visuomotor", jitter=0.0).trace(ep, CAM)
    assert tr.targets == ("goal",)
    np.testing.assert_allclose(tr.uv, ep.extras[f"goal_uv.{CAM}"], atol=1e-6)
    ep = synthetic_episode()
    ep.extras["contact"][:] = False
    ep.extras["grasp"][:] = False
    ep.extras["hand_pos"][:] = [-1.0, 0, 0]  # the hand never gets there
    tr = make_gaze_source("visuomotor", jitter=0.0).trace(ep, CAM)
    assert tr.arrivals[0] == 60 and (tr.target == 0).all()


def test_deterministic_jitter_blinks_and_dropouts():
    ep = synthetic_episode(T=4000, contact_at=1000)  # 50 s: enough blinks for the rate to show
    src = make_gaze_source("visuomotor", jitter=0.01, blink_rate_hz=2.0, missing_rate=0.1, seed=3)
    a, b = src.trace(ep, CAM), src.trace(ep, CAM)
    np.testing.assert_array_equal(a.uv, b.uv)
    np.testing.assert_array_equal(a.valid, b.valid)
    c = make_gaze_source("visuomotor", jitter=0.01, blink_rate_hz=2.0, missing_rate=0.1, seed=4).trace(
        ep, CAM
    )
    assert not np.array_equal(a.valid, c.valid)
    # dropouts (10%) + blinks (2/s x 0.12 s: about 22% of frames), overlapping: about 30%
    assert 0.22 < 1 - a.valid.mean() < 0.38
    assert np.isnan(a.uv[~a.valid]).all() and np.isfinite(a.uv[a.valid]).all()
    clean = make_gaze_source("visuomotor", jitter=0.01, seed=3).trace(ep, CAM)
    err = clean.uv[:900] - ep.extras[f"obj_uv.{CAM}"][:900]
    assert 0.004 < err.std() < 0.02 and abs(err.mean()) < 0.01  # jitter of about the asked size


def test_heatmaps_peak_at_the_gaze_point():
    ep = synthetic_episode()
    src = make_gaze_source("visuomotor", jitter=0.0, sigma=0.05)
    heat, valid = src(ep, CAM, (40, 50))
    assert heat.shape == (60, 40, 50) and heat.dtype == np.float32 and valid.all()
    np.testing.assert_allclose(heat.sum((1, 2)), 1.0, atol=1e-5)
    tr = src.trace(ep, CAM)
    for t in (0, 59):
        r, c = np.unravel_index(heat[t].argmax(), heat[t].shape)
        assert abs((c + 0.5) / 50 - tr.uv[t, 0]) <= 1 / 50 and abs((r + 0.5) / 40 - tr.uv[t, 1]) <= 1 / 40


def test_out_of_view_targets_are_invalid_and_missing_extras_are_named():
    ep = synthetic_episode()
    ep.extras[f"obj_uv.{CAM}"][:10] = [1.3, 0.5]
    heat, valid = make_gaze_source("visuomotor", jitter=0.0)(ep, CAM, (16, 16))
    assert not valid[:10].any() and valid[10:].all() and (heat[:10] == 0).all()
    del ep.extras[f"goal_uv.{CAM}"]
    with pytest.raises(ValueError, match="goal_uv.cam"):
        make_gaze_source("visuomotor")(ep, CAM, (16, 16))


@pytest.mark.sim
def test_on_a_real_pick_place_demonstration():
    """In a collected Meta-World episode, the gaze is on the puck until the grasp and near the goal after."""
    pytest.importorskip("metaworld")
    from gazereg.envs import MetaWorldEnv
    from gazereg.envs.metaworld.collector import rollout_expert
    from gazereg.envs.render import select_gl_backend

    env = MetaWorldEnv("pick-place-v3", cameras=("corner2",), image_size=96, gl_backend=select_gl_backend())
    ep, summary = rollout_expert(env, seed=1, max_steps=150)
    env.close()
    assert summary["success"]
    src = make_gaze_source("visuomotor", jitter=0.004)
    tr = src.trace(ep, "corner2")
    grasp = int(np.argmax(ep.extras["grasp"]))
    contact = int(np.argmax(ep.extras["contact"]))
    assert 0 < contact <= grasp < ep.length - 5
    obj, goal = ep.extras["obj_uv.corner2"], ep.extras["goal_uv.corner2"]
    px = 96
    before = np.linalg.norm(tr.uv[:contact] - obj[:contact], axis=1) * px
    assert before.max() < 3.0  # on the puck (about 2-3 px wide at 96 px)
    after = tr.switches[1] + 3
    assert after <= grasp + 10
    near_goal = np.linalg.norm(tr.uv[after:] - goal[after:], axis=1) * px
    assert near_goal.max() < 3.0
    heat, valid = src(ep, "corner2", (24, 24))
    assert valid.all() and heat.shape == (ep.length, 24, 24)
