"""`gazereg priors` checks its inputs before writing, writes its manifest last, sweeps killed writers'
temporaries, refuses priors of another store, and reports ordinary mistakes in one line."""

import shutil
import subprocess
import sys

import numpy as np
import pytest

from gazereg.cli import main as gazereg_main
from gazereg.data.store import MissingPriorError
from gazereg.gaze.priors import PriorsConfig, make_priors
from gazereg.gaze.sources.perturbed import PerturbedParams
from gazereg.runtime.errors import UsageError


@pytest.fixture
def store(tmp_path, recorded_gaze_store):
    """Three episodes with recorded gaze (tests/conftest.py)."""
    return recorded_gaze_store(tmp_path / "s")


def cfg(store, **kw):
    return PriorsConfig(store=store.root, **{"source": "recorded", "camera": "cam", "size": (8, 8), **kw})


def test_a_camera_the_store_lacks_leaves_nothing_and_the_rerun_works(store):
    with pytest.raises(
        UsageError, match="--camera 'wrist': episode 0 of store .* has no such camera; it has cam"
    ):
        make_priors(cfg(store, camera="wrist"), progress=False)
    assert not store.prior_dir("recorded").exists()
    assert make_priors(cfg(store), progress=False) == "recorded"  # the corrected run is not refused
    assert store.prior_info("recorded")["camera"] == "cam"


def test_the_manifest_is_written_last(tmp_path, recorded_gaze_store):
    store = recorded_gaze_store(tmp_path / "s", gaze=(True, True, False))  # episode 2 has no recorded gaze
    with pytest.raises(UsageError, match="episode 2 has no recorded gaze 'gaze_uv.cam'"):
        make_priors(cfg(store), progress=False)
    assert store.prior_indices("recorded") == [0, 1] and store.prior_names() == []
    assert not (store.prior_dir("recorded") / "prior.json").exists()
    with pytest.raises(MissingPriorError, match=r"incomplete \(2 of 3 episodes done\)"):
        store.prior_info("recorded")
    with pytest.raises(UsageError, match=r"other settings \(size: stored \[8, 8\], requested \[4, 4\]\)"):
        make_priors(cfg(store, size=(4, 4)), progress=False)  # files of the first settings exist
    make_priors(cfg(store, source="uniform", name="recorded", overwrite=True), progress=False)
    assert store.prior_info("recorded")["source"] == {"name": "uniform"}
    assert not (store.prior_dir("recorded") / "prior.pending.json").exists()


def test_sharded_runs_write_the_manifest_when_every_episode_is_done(store):
    make_priors(cfg(store, source="uniform"), rank=1, world=2, progress=False)
    assert store.prior_names() == []
    make_priors(cfg(store, source="uniform"), rank=0, world=2, progress=False)
    assert store.prior_names() == ["uniform"]


def test_killed_writers_temporaries_are_swept(store):
    folder = store.prior_dir("uniform")
    code = (
        "import os, sys\n"
        "from gazereg.runtime.io import atomic_path\n"
        "p = atomic_path(sys.argv[1] + '/ep_000000.npz'); p.__enter__().write_bytes(b'half')\n"
        "os._exit(0)\n"
    )
    subprocess.run([sys.executable, "-c", code, str(folder)], check=True)
    assert [p.name.endswith(".tmp") for p in folder.iterdir()] == [True]
    make_priors(cfg(store, source="uniform"), progress=False)
    assert sorted(p.name for p in folder.iterdir()) == [
        "ep_000000.npz",
        "ep_000001.npz",
        "ep_000002.npz",
        "prior.json",
    ]


def test_a_rerun_over_priors_copied_from_another_store_is_refused(tmp_path, recorded_gaze_store):
    a, b = recorded_gaze_store(tmp_path / "a"), recorded_gaze_store(tmp_path / "b", levels=(10, 11, 12))
    make_priors(cfg(a), progress=False)
    shutil.copytree(a.prior_dir("recorded"), b.prior_dir("recorded"))
    with pytest.raises(UsageError, match="was made from an episode with fingerprint .*another store"):
        make_priors(cfg(b), progress=False)
    make_priors(cfg(b, overwrite=True), progress=False)
    b.read_prior("recorded", 0)


def test_a_missing_base_prior_is_refused_before_anything_is_written(store):
    with pytest.raises(MissingPriorError, match="no priors named 'visuomotor'"):
        make_priors(cfg(store, source=PerturbedParams(mode="shuffle"), name="pert"), progress=False)
    assert not store.prior_dir("pert").exists()


def test_priors_values_are_unchanged(store):
    """The stored maps of a valid run are those of the uniform source (what the pipeline always wrote)."""
    make_priors(cfg(store, source="uniform"), progress=False)
    heat, valid = store.read_prior("uniform", 1)
    assert heat.shape == (6, 8, 8) and valid.all()
    np.testing.assert_array_equal(heat, np.float32(1 / 64))


@pytest.mark.parametrize(
    "args, message",
    [
        (["--source", "nope"], "unknown gaze source 'nope'; available: "),
        (["--camera", "wrist"], "--camera 'wrist': episode 0 of store "),
        (["--source-params", "sigma=-1"], "gaze source 'recorded': sigma must be > 0, got -1.0"),
        (["--store", "MISSING"], "is not an episode store (no store.json)"),
    ],
)
def test_ordinary_mistakes_are_one_line_and_exit_2(tmp_path, capsys, args, message, store):
    argv = ["priors", "--store", str(store.root), "--source", "recorded", "--camera", "cam", "--no-overwrite"]
    argv += [a.replace("MISSING", str(tmp_path / "none")) for a in args]
    assert gazereg_main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("gazereg priors: error: ") and message in err and err.count("\n") == 1
    assert not store.prior_dir("recorded").exists()


def test_the_module_entry_of_accelerate_launch_reports_one_line(store):
    argv = ["--store", str(store.root), "--source", "uniform", "--camera", "wrist"]
    done = subprocess.run(
        [sys.executable, "-m", "gazereg.gaze.priors", *argv], capture_output=True, text=True
    )
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert (
        done.stderr.strip().splitlines()[-1].startswith("gazereg priors: error: --camera 'wrist': episode 0")
    )
