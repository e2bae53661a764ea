"""`gazereg train` refuses, in one line and before any training, a gaze prior that does not fit what it would
regularize and a batch larger than the data (issue 33, items 1 and 3)."""

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from gazereg.cli import main as cli_main
from gazereg.data.dataset import EpisodeDataset
from gazereg.data.store import Episode, EpisodeStore
from gazereg.gaze.priors import PriorsConfig, make_priors
from gazereg.runtime.errors import UsageError
from gazereg.training import setup as training_setup
from gazereg.training.config import GazeConfig, smoke


@pytest.fixture(scope="module")
def two_cameras(tmp_path_factory) -> EpisodeStore:
    """Three episodes seen by corner2 and corner3 (48 px), uniform priors made for corner2."""
    rng = np.random.default_rng(0)
    store = EpisodeStore(tmp_path_factory.mktemp("two") / "demos", create=True)
    for _ in range(3):
        T = 10
        frames = {c: rng.integers(0, 255, (T, 48, 48, 3), dtype=np.uint8) for c in ("corner2", "corner3")}
        state, action = (
            rng.normal(0, 1, (T, 4)).astype(np.float32),
            rng.normal(0, 1, (T, 4)).astype(np.float32),
        )
        store.write(Episode("reach", "reach it", frames, state, action))
    make_priors(
        PriorsConfig(store=store.root, source="uniform", camera="corner2", size=(8, 8)), progress=False
    )
    return store


def train_argv(store, run, *more):
    return ["train", "--preset", "ci", "--data.store", str(store.root), "--run-dir", str(run), *more]


def refused(capsys, argv, run):
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and not run.exists()
    return err[0]


def test_a_prior_made_for_another_camera_is_refused(two_cameras, tmp_path, capsys):
    run = tmp_path / "run"
    line = refused(
        capsys, train_argv(two_cameras, run, "--gaze.prior", "uniform", "--gaze.camera", "corner3"), run
    )
    manifest = two_cameras.prior_dir("uniform") / "prior.json"
    assert line == (
        f"gazereg train: error: --gaze.camera corner3: prior 'uniform' was made for camera 'corner2' ({manifest}) "
        "and cannot regularize 'corner3'; make priors for it (gazereg priors --camera corner3 --name ...) or "
        "leave --gaze.camera out"
    )


def test_a_gaze_camera_the_policy_does_not_see_is_refused(two_cameras, tmp_path, capsys):
    run = tmp_path / "run"
    argv = train_argv(two_cameras, run, "--gaze.prior", "uniform", "--policy.cameras", "corner3")
    assert refused(capsys, argv, run) == (
        "gazereg train: error: --policy.cameras corner3: the policy does not see the gaze camera (prior "
        "'uniform''s camera 'corner2'); it sees corner3 of the store's corner2, corner3: add corner2 to "
        "--policy.cameras"
    )


def test_a_gaze_camera_the_store_lacks_is_refused(tiny_store, tmp_path, capsys):
    run = tmp_path / "run"
    argv = train_argv(tiny_store, run, "--gaze.prior", "square", "--gaze.camera", "corner3")
    assert refused(capsys, argv, run) == (
        f"gazereg train: error: --gaze.camera corner3: store {tiny_store.root} has no camera 'corner3'; it has cam"
    )


def test_a_prior_made_on_frames_of_another_size_is_refused(two_cameras, tmp_path, capsys):
    shutil.copytree(two_cameras.root, tmp_path / "copy")
    store = EpisodeStore(tmp_path / "copy")
    manifest = store.prior_dir("uniform") / "prior.json"
    info = json.loads(manifest.read_text())
    assert info["camera"] == "corner2" and info["image_hw"] == [48, 48]
    manifest.write_text(json.dumps({**info, "image_hw": [96, 96]}))
    run = tmp_path / "run"
    assert refused(capsys, train_argv(store, run, "--gaze.prior", "uniform"), run) == (
        f"gazereg train: error: prior 'uniform' was made on 'corner2' frames of 96x96 pixels ({manifest}), but "
        "the store's 'corner2' frames are 48x48: recompute it with `gazereg priors --overwrite`"
    )


@pytest.mark.parametrize("camera", [None, "corner2"])
def test_the_prior_camera_regularizes_itself(two_cameras, tmp_path, camera):
    base = smoke()
    c = dataclasses.replace(
        base,
        run_dir=tmp_path / "run",
        data=dataclasses.replace(base.data, store=Path(two_cameras.root)),
        gaze=GazeConfig(prior="uniform", camera=camera),
    )
    built = training_setup.build(c)
    assert built.gaze_camera == "corner2" and built.train_set.gaze_camera == "corner2"


def test_a_data_set_refuses_a_prior_for_another_camera(two_cameras):
    with pytest.raises(UsageError, match="prior 'uniform' was made for camera 'corner2', not 'corner3'"):
        EpisodeDataset(
            two_cameras, [0], ["corner2", "corner3"], 2, lambda t: (None, None), "uniform", "corner3", None
        )


# ----- item 3: the batch is bounded by the data ----------------------------------------------------------------
def test_a_batch_larger_than_the_training_samples_is_refused_before_any_allocation(
    tiny_store, tmp_path, capsys, monkeypatch
):
    def no_policy(*a, **k):
        raise AssertionError("the batch size must be checked before the policy and the data are made")

    monkeypatch.setattr(training_setup, "make_policy", no_policy)
    run = tmp_path / "run"
    # the tiny store: 4 episodes of 12 frames, one held out for validation -> 36 training samples
    assert refused(capsys, train_argv(tiny_store, run, "--batch-size", "100000"), run) == (
        f"gazereg train: error: --batch-size 100000 is larger than the 36 training samples of {tiny_store.root} "
        "(3 episodes, 1 held out for validation); use --batch-size 36 or less"
    )


def test_a_batch_of_every_training_sample_is_accepted(tiny_store, tmp_path):
    base = smoke()
    c = dataclasses.replace(
        base,
        run_dir=tmp_path / "run",
        batch_size=36,
        data=dataclasses.replace(base.data, store=Path(tiny_store.root)),
    )
    assert len(training_setup.build(c).train_set) == 36
    with pytest.raises(UsageError, match="--batch-size 37 is larger than the 36 training samples"):
        training_setup.build(dataclasses.replace(c, batch_size=37))
