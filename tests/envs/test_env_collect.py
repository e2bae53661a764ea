"""Demonstration collection: what it writes, resuming, failures, the command line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gazereg.envs.collect import _split_lists, collect, main
from gazereg.envs.collect_config import CollectConfig, CollectError, episode_index


def test_comma_lists_are_split():
    assert _split_lists(["--tasks", "a,b", "--episodes", "2"]) == ["--tasks", "a", "b", "--episodes", "2"]
    assert _split_lists(["--tasks=a,b", "--cameras", "c1", "c2,c3"]) == [
        "--tasks",
        "a",
        "b",
        "--cameras",
        "c1",
        "c2",
        "c3",
    ]
    assert _split_lists(["--out", "x,y"]) == ["--out", "x,y"]


def test_indices_are_a_function_of_task_slot_and_seed():
    assert episode_index(0, 0, 0) == 0
    assert episode_index(1, 5, 0) == 1005
    assert episode_index(2, 103, 100) == 2003


@pytest.fixture(scope="module")
def collected(tmp_path_factory, gl_backend):
    out = tmp_path_factory.mktemp("demos")
    cfg = CollectConfig(
        out=out,
        tasks=("reach-v3", "pick-place-v3"),
        episodes=2,
        image_size=48,
        cameras=("corner2", "topview"),
        max_steps=150,
        workers=1,
        progress=False,
        gl_backend=gl_backend,
    )
    return cfg, collect(cfg)


@pytest.mark.sim
def test_collection_writes_what_it_claims(collected):
    from gazereg.data.store import EpisodeStore

    cfg, report = collected
    assert report.complete and report.new_episodes == 4
    store = EpisodeStore(cfg.out)
    assert store.indices() == [0, 1, 1000, 1001]
    assert report.tasks["pick-place-v3"]["indices"] == [1000, 1001]
    total = 0
    for i in store.indices():
        ep = store.read(i)
        T = ep.length
        total += T
        assert ep.task == ("reach-v3" if i < 1000 else "pick-place-v3")
        assert ep.meta["seed"] == i % 1000 and ep.meta["success"] and ep.meta["fps"] == 80.0
        assert ep.meta["env"] == "metaworld" and ep.meta["env_name"] == ep.task
        assert ep.instruction.endswith(".")
        assert ep.frames["corner2"].shape == (T, 48, 48, 3) and ep.frames["topview"].shape == (T, 48, 48, 3)
        assert ep.state.shape == (T, 4) and ep.action.shape == (T, 4)
        for name in ("obj", "goal", "hand"):
            assert ep.extras[f"{name}_pos"].shape == (T, 3)
            for cam in ("corner2", "topview"):
                uv = ep.extras[f"{name}_uv.{cam}"]
                assert uv.shape == (T, 2) and np.isfinite(uv).all()
        for name in ("contact", "grasp", "success"):
            assert ep.extras[name].shape == (T,) and ep.extras[name].dtype == bool
        assert ep.extras["success"][-1] and not ep.extras["success"][:-1].any()
        np.testing.assert_allclose(
            ep.state[:, :3], ep.extras["hand_pos"], atol=0.05
        )  # hand body vs pad centre
        assert ep.meta["camera_geometry"]["corner2"]["rot180"] is True
    assert total == report.new_frames
    pp = store.read(1000)
    assert pp.extras["grasp"].any() and pp.extras["contact"].any()  # the pick-place expert grasps the puck
    assert not store.read(0).extras["contact"].any()  # reaching touches nothing
    on_disk = json.loads((Path(cfg.out) / "collect" / "report.json").read_text())
    assert on_disk["new_episodes"] == 4 and on_disk["complete"]


def _dead_pid() -> int:
    """The PID of a process that has exited."""
    done = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    return int(done.stdout)


@pytest.mark.sim
def test_rerun_resumes_without_touching_episodes(collected):
    cfg, _ = collected
    ep_dir = Path(cfg.out) / "episodes" / "ep_001000"
    before = (ep_dir / "meta.json").stat().st_mtime_ns
    stale = Path(cfg.out) / "episodes" / f".ep_000002.{_dead_pid()}.abcd1234.tmp"  # a killed writer's
    stale.mkdir()
    report = collect(cfg)
    assert not stale.exists()  # swept at the start
    assert report.complete and report.new_episodes == 0
    assert report.tasks["reach-v3"]["resumed"] == 2
    assert (ep_dir / "meta.json").stat().st_mtime_ns == before
    # More episodes: only the missing ones are collected, at the indices that (task, seed) determine.
    from dataclasses import replace

    from gazereg.data.store import EpisodeStore

    report = collect(replace(cfg, tasks=("reach-v3",), episodes=3))
    assert report.new_episodes == 1 and 2 in EpisodeStore(cfg.out)


@pytest.mark.sim
def test_mismatched_rerun_is_refused(collected):
    from dataclasses import replace

    cfg, _ = collected
    with pytest.raises(CollectError, match="holds task"):
        collect(replace(cfg, tasks=("pick-place-v3",)))
    with pytest.raises(CollectError, match="other settings"):
        collect(replace(cfg, image_size=32))
    with pytest.raises(CollectError, match=r"--tasks: unknown Meta-World task\(s\) \['juggle-v3'\]"):
        collect(replace(cfg, tasks=("reach-v3", "juggle-v3")))


@pytest.mark.sim
def test_failures_are_reported_not_stored(tmp_path, gl_backend):
    from gazereg.data.store import EpisodeStore

    cfg = CollectConfig(
        out=tmp_path,
        tasks=("pick-place-v3",),
        episodes=1,
        max_failures=1,
        image_size=32,
        max_steps=5,
        workers=1,
        progress=False,
        gl_backend=gl_backend,
    )
    report = collect(cfg)
    assert not report.complete
    assert set(report.tasks["pick-place-v3"]["failed_seeds"]) == {"0", "1"}
    assert len(EpisodeStore(tmp_path)) == 0
    lines = (tmp_path / "collect" / "attempts.jsonl").read_text().splitlines()
    assert [json.loads(x)["record"]["success"] for x in lines] == [False, False]
    # a rerun with the same settings does not retry the seeds that failed
    again = collect(cfg)
    assert "skipped" in again.tasks["pick-place-v3"]["failed_seeds"]["0"]
    assert len((tmp_path / "collect" / "attempts.jsonl").read_text().splitlines()) == 2


@pytest.mark.sim
def test_command_line_with_comma_separated_tasks(tmp_path, gl_backend, capsys):
    rc = main(
        [
            "--preset",
            "demos-2x2",
            "--tasks",
            "reach-v3,button-press-topdown-v3",
            "--episodes",
            "1",
            "--out",
            str(tmp_path),
            "--workers",
            "1",
            "--no-progress",
            "--gl-backend",
            gl_backend,
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert "reach-v3" in out and "button-press-topdown-v3" in out and "1/1 episodes" in out
    cfg = json.loads((tmp_path / "collect" / "config.json").read_text())
    assert cfg["tasks"] == ["reach-v3", "button-press-topdown-v3"] and cfg["image_size"] == 64


@pytest.mark.sim
@pytest.mark.slow
def test_parallel_workers_give_the_same_episodes(tmp_path, gl_backend):
    """Two worker processes write the same episodes (bit for bit) as one process."""
    from gazereg.data.store import EpisodeStore

    common = dict(
        tasks=("reach-v3",),
        episodes=2,
        image_size=32,
        max_steps=150,
        progress=False,
        gl_backend=gl_backend,
        action_noise=0.1,
    )
    r1 = collect(CollectConfig(out=tmp_path / "one", workers=1, **common))
    r2 = collect(CollectConfig(out=tmp_path / "two", workers=2, **common))
    assert r1.complete and r2.complete
    a, b = EpisodeStore(tmp_path / "one"), EpisodeStore(tmp_path / "two")
    assert a.indices() == b.indices()
    for i in a.indices():
        ea, eb = a.read(i), b.read(i)
        np.testing.assert_array_equal(ea.frames["corner2"], eb.frames["corner2"])
        np.testing.assert_array_equal(ea.action, eb.action)


@pytest.mark.sim
def test_perturbed_collection_is_the_same_episode_under_other_light(tmp_path, gl_backend):
    """dim:0.7 renders the same setups and expert actions as clean, only darker, into a store of its own."""
    from gazereg.data.store import EpisodeStore
    from gazereg.envs.collect_config import fingerprint, resolve

    common = dict(
        tasks=("reach-v3",), episodes=1, image_size=32, workers=1, progress=False, gl_backend=gl_backend
    )
    clean, dim = (
        CollectConfig(out=tmp_path / "clean", **common),
        CollectConfig(out=tmp_path / "dim", perturbation="dim:0.7", **common),
    )
    assert collect(clean).complete and collect(dim).complete
    a, b = EpisodeStore(tmp_path / "clean"), EpisodeStore(tmp_path / "dim")
    assert a.indices() == b.indices()
    ea, eb = a.read(a.indices()[0]), b.read(b.indices()[0])
    np.testing.assert_array_equal(ea.action, eb.action)
    fa, fb = ea.frames["corner2"].astype(float), eb.frames["corner2"].astype(float)
    assert fb.mean() < 0.95 * fa.mean()
    assert fingerprint(resolve(clean)) != fingerprint(resolve(dim))


def test_bad_perturbation_is_refused_by_name(tmp_path):
    with pytest.raises(CollectError, match="--perturbation 'darker:0.5': unknown perturbation 'darker'"):
        collect(CollectConfig(out=tmp_path, tasks=("reach-v3",), perturbation="darker:0.5", progress=False))


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"episodes": 0}, "--episodes must be an integer in [1, 1000], got 0"),
        ({"episodes": 990, "max_failures": 20}, "--max-failures must be an integer in [0, 10], got 20"),
        ({"seed_base": -1}, "--seed-base must be"),
        ({"max_steps": -1}, "--max-steps must be"),
        ({"workers": -1}, "--workers must be"),
        ({"image_size": 4}, "--image-size must be an integer >= 8, got 4"),
        ({"action_noise": float("nan")}, "--action-noise must be"),
        ({"goal_marker_radius": -0.1}, "--goal-marker-radius must be"),
        ({"tasks": ()}, "--tasks is empty"),
        ({"tasks": ("reach-v3", "reach-v3")}, "--tasks lists 'reach-v3' more than once"),
        ({"cameras": ("corner2", "corner2")}, "--cameras lists 'corner2' more than once"),
        ({"perturbation": "dim:3"}, "--perturbation 'dim:3': severity must be in [0, 1]"),
        ({"env": "libero", "perturbation": "fog:0.5"}, "unknown perturbation 'fog'"),
        ({"env": "bullet"}, "--env: unknown simulator 'bullet'"),
    ],
)
def test_bad_settings_are_refused_when_the_config_is_built(changes, message):
    from gazereg.runtime.errors import UsageError

    with pytest.raises(UsageError) as refused:
        CollectConfig(**changes)
    assert message in str(refused.value)


def test_more_steps_than_the_simulator_allows_are_refused_by_option():
    pytest.importorskip("metaworld")
    from gazereg.envs.base import make_collector
    from gazereg.envs.collect_config import resolve

    limit = make_collector("metaworld").max_steps_limit
    with pytest.raises(CollectError, match=f"--max-steps must be <= {limit} for metaworld, got {limit + 1}"):
        resolve(CollectConfig(tasks=("reach-v3",), max_steps=limit + 1))


def test_the_command_line_raises_rather_than_printing(tmp_path, monkeypatch):
    """`main` leaves the error line and the exit status to `gazereg`: bad settings and an incomplete
    collection are exceptions."""
    import gazereg.envs.collect as collect_module
    from gazereg.envs.collect import CollectionIncomplete, CollectReport

    with pytest.raises(CollectError, match="--perturbation 'fog'"):
        main(["--out", str(tmp_path), "--perturbation", "fog"])
    incomplete = CollectReport(tasks={}, seconds=1.0, new_episodes=0, new_frames=0, complete=False)
    monkeypatch.setattr(collect_module, "collect", lambda cfg: incomplete)
    with pytest.raises(CollectionIncomplete, match="fewer episodes than asked for"):
        main(["--out", str(tmp_path)])
