"""The `visuomotor` gaze source on Gym-Aloha's per-frame extras (two hands, two objects), and the `aloha`
experiment preset; neither needs gym-aloha (the simulator's own tests: tests_aloha/, scripts/aloha_lane.sh)."""

from __future__ import annotations

import numpy as np
import pytest

from gazereg.data.store import Episode
from gazereg.gaze.sources.visuomotor import VisuomotorGaze, VisuomotorParams


def bimanual_episode(T: int = 120) -> Episode:
    """An insertion-like episode at 50 fps: the right hand touches the peg (obj) from frame 30, the left hand
    the socket (obj2) from frame 70; the right hand's generic `contact` is on from frame 30 too."""
    uv = {
        "obj": (0.6, 0.5),
        "obj2": (0.4, 0.5),
        "goal": (0.5, 0.4),
    }
    extras = {f"{k}_uv.top": np.tile(np.float32(v), (T, 1)) for k, v in uv.items()}
    for k in ("obj", "obj2", "hand"):
        extras[f"{k}_pos"] = np.zeros((T, 3), np.float32)
    extras["goal_pos"] = np.full((T, 3), 5.0, np.float32)  # far: the goal is reached by success only
    contact_obj = np.arange(T) >= 30
    contact_obj2 = np.arange(T) >= 70
    extras.update(
        {
            "contact": contact_obj,
            "grasp": contact_obj,
            "contact.obj": contact_obj,
            "contact.obj2": contact_obj2,
            "success": np.zeros(T, bool),
        }
    )
    return Episode(
        task="AlohaInsertion-v0",
        instruction="insert the peg into the socket",
        frames={"top": np.zeros((T, 8, 8, 3), np.uint8)},
        state=np.zeros((T, 14), np.float32),
        action=np.zeros((T, 14), np.float32),
        extras=extras,
        meta={"seed": 0, "fps": 50.0, "gaze_targets": ["obj", "obj2", "goal"]},
        index=0,
    )


def test_visuomotor_follows_the_episodes_own_targets_and_each_hands_contact():
    """The episode's meta names peg, socket, meeting point: the eyes visit all three in that order; the
    socket's arrival is the left hand's contact with it (frame 70), not the right hand's generic contact
    (frame 30), so the eyes switch to the socket lead_time_s (0.2 s = 10 frames) before frame 70."""
    ep = bimanual_episode()
    gaze = VisuomotorGaze(VisuomotorParams(lead_time_s=0.2, dwell_s=0.0, jitter=0.0))
    tr = gaze.trace(ep, "top")
    assert tr.targets == ("obj", "obj2", "goal")
    assert tr.arrivals == (30, 70, ep.length)
    assert tr.switches[1] == 60
    assert np.allclose(tr.uv[:30], (0.6, 0.5)) and np.allclose(tr.uv[62:70], (0.4, 0.5))


def test_explicit_targets_still_override_the_episodes():
    tr = VisuomotorGaze(VisuomotorParams(targets=("obj", "goal"), jitter=0.0)).trace(
        bimanual_episode(), "top"
    )
    assert tr.targets == ("obj", "goal")


def test_the_aloha_preset():
    """Baseline, gaze, the two gaze controls and uniform on both tasks from the top camera; 50 evaluation
    episodes per task at the env's 400 steps on setups no demonstration (nor a replacement for a failed one)
    starts from, the first 25 of them again dimmed and with sensor noise."""
    from gazereg.experiment.config import PRESETS

    cfg = PRESETS["aloha"]()
    assert cfg.env == cfg.eval.env == "aloha"
    assert cfg.tasks == cfg.eval.tasks == ("AlohaTransferCube-v0", "AlohaInsertion-v0")
    assert cfg.camera == "top" and set(cfg.arms) == {"baseline", "gaze", "same_task", "perturbed", "uniform"}
    assert cfg.eval.episodes == 50 and cfg.eval.max_steps == 400
    assert cfg.demos_per_task + cfg.demo_max_failures <= cfg.eval.seed_start
    assert cfg.eval.conditions == ("clean", "dim:0.7", "gaussian_noise:0.5")
    assert list(cfg.eval.seeds("dim:0.7")) == list(cfg.eval.seeds("clean"))[:25]


def test_unknown_simulator_lists_aloha():
    from gazereg.envs.base import UnknownSimulator, simulator

    with pytest.raises(UnknownSimulator, match="'aloha'"):
        simulator("nosuch")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--tasks", "nosuch"], "unknown Gym-Aloha task 'nosuch'"),
        (["--seeds", "0", "0"], "--seeds takes FIRST >= 0 and COUNT >= 1, got 0 0"),
    ],
)
def test_measure_refuses_bad_input_in_one_line_before_any_work(argv, message, capsys):
    from gazereg.envs.aloha.measure import main

    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
