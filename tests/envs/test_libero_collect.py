"""LIBERO end to end: expert demos -> visuomotor priors -> a few training steps with the gaze term -> evaluation.

Needs the LIBERO venv: `bash scripts/libero_env.sh pytest -m slow tests/envs/test_libero_collect.py`; skipped
where hf-libero / robosuite / the assets packages are missing. The parts that need no LIBERO run everywhere."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from gazereg.envs.collect import collect
from gazereg.envs.collect_config import CollectConfig, CollectError, fingerprint, resolve
from gazereg.envs.libero.setup import libero_available

CAMERAS = ("agentview_rgb", "eye_in_hand_rgb")  # as `gazereg import hdf5` names LIBERO's cameras


def test_unknown_simulator_and_missing_libero_are_clear_errors(tmp_path):
    with pytest.raises(CollectError, match="unknown simulator"):
        collect(CollectConfig(out=tmp_path, env="bullet", tasks=("x",)))  # type: ignore[arg-type]
    if not libero_available()[0]:
        with pytest.raises(CollectError, match="scripts/libero_env.sh"):
            collect(CollectConfig(out=tmp_path, env="libero", tasks=("libero_spatial/0",)))


def test_metaworld_defaults_and_fingerprint_are_unchanged():
    pytest.importorskip("metaworld")
    cfg = resolve(CollectConfig())
    assert cfg.cameras == ("corner2",) and cfg.max_steps == 200
    # the fingerprint of Meta-World stores made before `env` existed
    assert fingerprint(cfg) == fingerprint(resolve(CollectConfig(cameras=("corner2",), max_steps=200)))


@pytest.mark.slow
@pytest.mark.libero
def test_libero_task_specs_are_canonical():
    cfg = resolve(CollectConfig(env="libero", tasks=("libero_spatial",)))
    assert cfg.tasks == tuple(f"libero_spatial/{i}" for i in range(10))
    assert cfg.cameras == CAMERAS and cfg.max_steps == 220
    name = "pick_up_the_black_bowl_on_the_stove_and_place_it_on_the_plate"
    assert resolve(CollectConfig(env="libero", tasks=(f"libero_spatial/{name}",))).tasks == (
        "libero_spatial/7",
    )
    assert resolve(CollectConfig(env="libero", tasks=("libero_10/3",))).tasks == ("libero_10/3",)
    with pytest.raises(CollectError, match="no task"):
        resolve(CollectConfig(env="libero", tasks=("libero_spatial/nope",)))


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    out = tmp_path_factory.mktemp("libero_demos")
    cfg = CollectConfig(
        out=out,
        env="libero",
        tasks=("libero_spatial/0",),
        episodes=2,
        max_failures=2,
        image_size=48,
        workers=1,
        progress=False,
    )
    return cfg, collect(cfg)


@pytest.mark.slow
@pytest.mark.libero
def test_collect_writes_libero_episodes(demos):
    from gazereg.data.store import EpisodeStore
    from gazereg.envs.libero.collector import LiberoCollector

    cfg, report = demos
    assert report.complete and report.tasks["libero_spatial/0"]["episodes"] == 2
    store = EpisodeStore(cfg.out)
    for i in store.indices():
        ep = store.read(i)
        T = ep.length
        assert ep.task == "pick_up_the_black_bowl_between_the_plate_and_the_ramekin_and_place_it_on_the_plate"
        assert (
            ep.instruction == ep.task.replace("_", " ") == LiberoCollector().instruction("libero_spatial/0")
        )
        assert set(ep.frames) == set(CAMERAS)
        assert all(f.shape == (T, 48, 48, 3) for f in ep.frames.values())
        assert ep.state.shape == (T, 8) and ep.action.shape == (T, 7)
        assert ep.meta["env"] == "libero" and ep.meta["fps"] == 20.0 and ep.meta["success"]
        assert ep.meta["setup"] == {
            "benchmark": "libero",
            "suite": "libero_spatial",
            "task_index": 0,
            "init_state": i,
        }
        for k in ("obj", "goal", "hand"):
            assert ep.extras[f"{k}_pos"].shape == (T, 3)
            for cam in CAMERAS:
                assert ep.extras[f"{k}_uv.{cam}"].shape == (T, 2)
        assert ep.extras["grasp"].any() and ep.extras["success"][-1]
        uv = ep.extras["obj_uv.agentview_rgb"]
        assert ((uv > 0) & (uv < 1)).all()  # the bowl is in the agentview image throughout
    saved = json.loads((Path(cfg.out) / "collect" / "config.json").read_text())
    assert saved["cameras"] == list(CAMERAS) and saved["env"] == "libero"
    again = collect(cfg)  # resumes: nothing new
    assert again.new_episodes == 0 and again.tasks["libero_spatial/0"]["resumed"] == 2


@pytest.mark.slow
@pytest.mark.libero
def test_priors_train_and_eval_on_libero(demos, tmp_path):
    """visuomotor priors on the collected episodes, the tiny VLA trained a few steps with the gaze term, and
    `gazereg eval --env libero` on that checkpoint: the policy's cameras are LiberoEnv's."""
    from gazereg.evaluation.config import EvalConfig
    from gazereg.evaluation.rollout import evaluate
    from gazereg.gaze.priors import PriorsConfig, make_priors
    from gazereg.training.config import DataConfig, GazeConfig, smoke
    from gazereg.training.loop import train

    cfg, _ = demos
    name = make_priors(
        PriorsConfig(store=cfg.out, source="visuomotor", camera="agentview_rgb"), progress=False
    )
    heat = np.load(Path(cfg.out) / "priors" / name / "ep_000000.npz")
    assert heat["valid"].mean() > 0.9

    tcfg = dataclasses.replace(
        smoke(),
        run_dir=tmp_path / "run",
        steps=4,
        save_every=4,
        eval_every=4,
        data=DataConfig(store=cfg.out, val_fraction=0.0),
        gaze=GazeConfig(prior=name, weight=0.1),
    )
    result = train(tcfg)
    assert np.isfinite(result["metrics"]["loss/gaze_kl"])
    ckpt = Path(result["checkpoint"])
    assert tuple(json.loads((ckpt / "config.json").read_text())["cameras"]) == CAMERAS

    info = evaluate(
        EvalConfig(
            checkpoints=(f"gaze={ckpt}",),
            tasks=("libero_spatial/0",),
            episodes=1,
            seed_start=40,
            max_steps=5,
            workers=1,
            videos=1,
            env="libero",
            out=tmp_path / "eval",
        ),
        progress=False,
    )
    (rec,) = info["episodes"]
    assert rec["length"] == 5 and rec["success"] is False
    assert Path(rec["video"]).stat().st_size > 0
