from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gazereg.cli import main as gazereg_main
from gazereg.data.store import Episode, EpisodeStore
from gazereg.gaze.priors import PriorsCommand, PriorsConfig, main, make_priors
from gazereg.gaze.sources import available_gaze_sources, make_gaze_source, parse_source_params
from gazereg.gaze.sources.glc import GLCParams
from gazereg.gaze.sources.perturbed import PerturbedParams
from gazereg.gaze.sources.visuomotor import VisuomotorParams
from gazereg.runtime.errors import UsageError


def square_episode(T=6, hw=(32, 32), pos=(0.25, 0.75)):
    """Grey frames with a bright square at (u, v) = pos; recorded gaze on the square."""
    frames = np.full((T, *hw, 3), 90, np.uint8)
    cy, cx = int(pos[1] * hw[0]), int(pos[0] * hw[1])
    frames[:, cy - 3 : cy + 3, cx - 3 : cx + 3] = 255
    gaze = np.tile(np.array(pos, np.float32), (T, 1))
    gaze[1] = np.nan
    return Episode(
        task="t",
        instruction="look at the square",
        frames={"cam": frames},
        state=np.zeros((T, 2), np.float32),
        action=np.zeros((T, 2), np.float32),
        extras={"gaze_uv.cam": gaze},
    )


@pytest.fixture
def store(tmp_path):
    s = EpisodeStore(tmp_path / "store", create=True)
    for k in range(3):
        s.write(square_episode(T=5 + k))
    return s


def test_registry_lists_builtins_and_rejects_unknown():
    assert {"uniform", "saliency", "perturbed", "recorded", "visuomotor", "glc", "glc_folds"} <= set(
        available_gaze_sources()
    )
    with pytest.raises(
        UsageError, match="unknown gaze source 'nope'; available: glc, glc_folds, perturbed, recorded"
    ):
        make_gaze_source("nope")
    with pytest.raises(UsageError, match="bad parameters for gaze source 'uniform'"):
        make_gaze_source("uniform", sigma=1)


def test_saliency_peaks_on_the_salient_square():
    heat, valid = make_gaze_source("saliency")(square_episode(), "cam", (16, 16))
    assert valid.all() and np.allclose(heat.sum((1, 2)), 1, atol=1e-5)
    i, j = np.unravel_index(heat[0].argmax(), heat[0].shape)
    assert abs(i - 12) <= 2 and abs(j - 4) <= 2


def test_recorded_gaze_marks_lost_frames_invalid():
    heat, valid = make_gaze_source("recorded")(square_episode(), "cam", (16, 16))
    assert valid.tolist() == [True, False, True, True, True, True]
    assert np.unravel_index(heat[0].argmax(), heat[0].shape) == (11, 3)
    with pytest.raises(UsageError, match="no recorded gaze 'gaze_uv.wrist'"):
        make_gaze_source("recorded")(square_episode(), "wrist", (16, 16))


def test_priors_pipeline_resumes_and_refuses_changed_settings(store):
    cfg = PriorsConfig(store=store.root, source="recorded", camera="cam", size=(16, 16))
    assert make_priors(cfg, progress=False) == "recorded"
    info = store.prior_info("recorded")
    assert info["source"]["name"] == "recorded" and info["camera"] == "cam"
    heat, valid = store.read_prior("recorded", 0)
    assert valid.all()  # the lost frame is filled by its neighbours (window 2+2)
    mtime = (store.prior_dir("recorded") / "ep_000000.npz").stat().st_mtime_ns
    make_priors(cfg, progress=False)  # resume: nothing recomputed
    assert (store.prior_dir("recorded") / "ep_000000.npz").stat().st_mtime_ns == mtime
    with pytest.raises(UsageError, match=r"other settings \(size: stored \[16, 16\], requested \[8, 8\]\)"):
        make_priors(
            PriorsConfig(store=store.root, source="recorded", camera="cam", size=(8, 8)), progress=False
        )


def test_sharded_priors_cover_every_episode_once(store):
    cfg = PriorsConfig(store=store.root, source="uniform", camera="cam", size=(8, 8))
    make_priors(cfg, rank=1, world=2, progress=False)
    assert [store.has_prior("uniform", i) for i in store.indices()] == [False, True, False]
    make_priors(cfg, rank=0, world=2, progress=False)
    assert all(store.has_prior("uniform", i) for i in store.indices())


@pytest.mark.parametrize("mode", ["blobs", "shuffle", "other_episode", "same_task"])
def test_perturbed_controls(store, mode):
    make_priors(
        PriorsConfig(store=store.root, source="recorded", camera="cam", size=(16, 16)), progress=False
    )
    params = PerturbedParams(mode=mode, base="recorded", block=4)
    make_priors(
        PriorsConfig(
            store=store.root,
            source=params,
            name=f"p_{mode}",
            camera="cam",
            size=(16, 16),
        ),
        progress=False,
    )
    base, _ = store.read_prior("recorded", 0)
    pert, valid = store.read_prior(f"p_{mode}", 0)
    assert valid.any() and np.allclose(pert[valid].sum((1, 2)), 1, atol=1e-5)
    assert pert.shape == base.shape
    if mode == "shuffle":  # same values, other places
        np.testing.assert_allclose(np.sort(pert[0].ravel()), np.sort(base[0].ravel()), atol=1e-6)
        assert not np.allclose(pert[0], base[0])


def test_same_task_gives_each_episode_another_demonstration_of_its_own_task(tmp_path):
    """Two tasks whose gaze sits in opposite corners, three episodes each (gaze shifted per episode):
    every same_task prior peaks where another episode of its own task looked, never where its own episode
    or the other task looked; a task with a single episode is refused."""
    s = EpisodeStore(tmp_path / "store", create=True)
    tasks = {}
    for task, (u, v) in (("a", (0.25, 0.25)), ("b", (0.75, 0.75))):
        for k in range(3):
            tasks[s.write(replace(square_episode(T=4 + k, pos=(u + 0.12 * k, v)), task=task))] = task
    size = (16, 16)
    make_priors(PriorsConfig(store=s.root, source="recorded", camera="cam", size=size), progress=False)
    params = PerturbedParams(mode="same_task", base="recorded")
    make_priors(PriorsConfig(store=s.root, source=params, name="st", camera="cam", size=size), progress=False)

    def peak(name, i):
        heat, valid = s.read_prior(name, i)
        return np.unravel_index(heat[valid][0].argmax(), size)

    places = {i: peak("recorded", i) for i in tasks}
    assert len(set(places.values())) == len(places)  # every episode looked somewhere else
    for i, task in tasks.items():
        got = peak("st", i)
        source = [j for j, place in places.items() if place == got]
        assert source and source[0] != i and tasks[source[0]] == task

    lone = EpisodeStore(tmp_path / "lone", create=True)
    lone.write(replace(square_episode(T=4), task="a"))
    lone.write(replace(square_episode(T=4), task="b"))
    make_priors(PriorsConfig(store=lone.root, source="recorded", camera="cam", size=size), progress=False)
    with pytest.raises(UsageError, match="at least two episodes of task 'a'"):
        make_priors(
            PriorsConfig(store=lone.root, source=params, name="st", camera="cam", size=size), progress=False
        )


def test_source_params_from_the_command_line_are_typed_once():
    assert parse_source_params("perturbed", ["mode=blobs", "block=4"]) == PerturbedParams(
        mode="blobs", block=4
    )
    glc = parse_source_params("glc", ["checkpoint=runs/glc/final", "stride=1", "temperature=null"])
    assert glc == GLCParams(checkpoint=Path("runs/glc/final"), stride=1, temperature=None)
    vm = parse_source_params("visuomotor", ["targets=obj,goal", "fps=80"])
    assert vm == VisuomotorParams(targets=("obj", "goal"), fps=80.0)
    assert parse_source_params("visuomotor", ['targets=["goal"]']).targets == ("goal",)
    with pytest.raises(UsageError, match="key=value"):
        parse_source_params("glc", ["oops"])
    with pytest.raises(
        UsageError, match="has no parameter 'strid'; its parameters: checkpoint, config, stride"
    ):
        parse_source_params("glc", ["strid=1"])
    with pytest.raises(UsageError, match="bad value stride='two': expected an integer"):
        parse_source_params("glc", ["stride=two"])
    with pytest.raises(UsageError, match="bad value mode='middle': choose one of centre, average"):
        parse_source_params("glc", ["mode=middle"])
    with pytest.raises(UsageError, match="gaze source 'recorded': sigma must be > 0, got -1.0"):
        parse_source_params("recorded", ["sigma=-1"])
    with pytest.raises(UsageError, match="unknown gaze source 'nope'"):
        parse_source_params("nope", [])


def test_params_are_checked_when_made():
    with pytest.raises(UsageError, match="jitter_rho"):
        VisuomotorParams(jitter_rho=1.0)
    with pytest.raises(UsageError, match="unknown perturbation"):
        PerturbedParams(mode="flip")  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="once"):
        make_gaze_source(VisuomotorParams(), jitter=0.0)
    assert make_gaze_source(VisuomotorParams(jitter=0.0)).describe()["jitter"] == 0.0


def test_priors_command_converts_its_text_parameters(store, capsys):
    cmd = PriorsCommand(store=store.root, source="perturbed", source_params=("mode=blobs",), name="b")
    assert cmd.config().source == PerturbedParams(mode="blobs") and cmd.config().name == "b"
    argv = [
        "--store",
        str(store.root),
        "--source",
        "uniform",
        "--source-params",
        "sigma=1",
        "--camera",
        "cam",
    ]
    assert gazereg_main(["priors", *argv]) == 2
    err = capsys.readouterr().err
    assert (
        err == "gazereg priors: error: gaze source 'uniform' has no parameter 'sigma'; its parameters: none\n"
    )
    with pytest.raises(UsageError, match="has no parameter 'sigma'"):
        main(argv)
