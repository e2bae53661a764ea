"""One `gazereg priors` run writes a prior at a time, and a prior's files are checkably one setting (issue 33,
item 2); prior.json records the camera's frame size (item 1)."""

import dataclasses
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gazereg.cli import main as gazereg_main
from gazereg.gaze.priors import LOCK_FILE, PriorsConfig, make_priors, writer_lock
from gazereg.runtime.errors import UsageError

ROOT = Path(__file__).resolve().parents[2]

# A real `gazereg priors` run that stops before aggregating its first episode until GO exists (STARTED says it
# got there), so a second run can be started while it works.
BLOCKING_RUN = """
import sys, time
from pathlib import Path
import gazereg.gaze.priors as priors
started, go = Path(sys.argv[1]), Path(sys.argv[2])
real = priors.aggregate
def waiting(*a, **k):
    started.touch()
    deadline = time.time() + 120
    while not go.exists() and time.time() < deadline:
        time.sleep(0.05)
    return real(*a, **k)
priors.aggregate = waiting
from gazereg.cli import main
raise SystemExit(main(["priors", *sys.argv[3:]]))
"""


@pytest.fixture
def store(tmp_path, recorded_gaze_store):
    """Three episodes with recorded gaze (tests/conftest.py), frames 16 x 12: not square, so the manifest's
    frame size shows its order."""
    return recorded_gaze_store(tmp_path / "s", hw=(16, 12))


def argv(store, *more):
    return ["--store", str(store.root), "--source", "recorded", "--camera", "cam", "--size", "8", "8", *more]


def start_blocking_run(store, tmp_path, *more):
    started, go = tmp_path / "started", tmp_path / "go"
    proc = subprocess.Popen(
        [sys.executable, "-c", BLOCKING_RUN, str(started), str(go), *argv(store, *more)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.time() + 120
    while not started.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.time() < deadline, "the first run did not start"
        time.sleep(0.05)
    return proc, go


def files_settings(store, name):
    return {i: store.prior_settings(name, i) for i in store.prior_indices(name)}


def test_a_second_run_while_one_writes_is_refused_naming_the_holder(tmp_path, capsys, store):
    first, go = start_blocking_run(store, tmp_path)  # defaults (aggregation past 2)
    try:
        status = gazereg_main(["priors", *argv(store, "--aggregation.past", "6")])
        err = capsys.readouterr().err
    finally:
        go.touch()
        out, first_err = first.communicate(timeout=120)
    assert first.returncode == 0, first_err
    assert status == 2 and err.count("\n") == 1
    lock = store.prior_dir("recorded") / LOCK_FILE
    assert err == (
        f"gazereg priors: error: priors 'recorded' in {store.root} are being written by another `gazereg "
        f"priors` run (process {first.pid} holds {lock}); wait for it to finish, or use --name to store these "
        "separately\n"
    )
    info = store.prior_info("recorded")
    assert info["aggregation"]["past"] == 2
    assert set(files_settings(store, "recorded").values()) == {info["settings_fingerprint"]}
    assert sorted(p.name for p in store.prior_dir("recorded").iterdir()) == [
        "ep_000000.npz",
        "ep_000001.npz",
        "ep_000002.npz",
        "prior.json",
    ]  # the lock file goes with the run


def test_a_killed_writer_releases_its_lock(tmp_path, store):
    first, _ = start_blocking_run(store, tmp_path)
    os.kill(first.pid, signal.SIGKILL)
    first.communicate(timeout=60)
    assert (store.prior_dir("recorded") / LOCK_FILE).exists()  # left behind, but no longer locked
    assert gazereg_main(["priors", *argv(store)]) == 0
    assert not (store.prior_dir("recorded") / LOCK_FILE).exists()


def test_the_processes_of_one_sharded_run_share_the_lock_and_exclude_others(store):
    cfg = PriorsConfig(store=store.root, source="recorded", camera="cam", size=(8, 8))
    with writer_lock(store, "recorded", rank=0, world=2), writer_lock(store, "recorded", rank=1, world=2):
        with pytest.raises(UsageError, match="are being written by another `gazereg priors` run"):
            make_priors(cfg, progress=False)  # an unsharded run
        with pytest.raises(UsageError, match=r"\.writing\.rank1\.lock"):
            make_priors(cfg, rank=1, world=2, progress=False)  # rank 1 of another sharded run
    make_priors(cfg, rank=1, world=2, progress=False)
    make_priors(cfg, rank=0, world=2, progress=False)
    assert store.prior_names() == ["recorded"]
    assert sorted(p.name for p in store.prior_dir("recorded").iterdir())[0] == "ep_000000.npz"


def test_a_file_of_another_setting_is_refused_by_readers_and_reruns(store):
    """The lock aside (e.g. two machines on a network file system): a file written with other settings is
    found by its settings fingerprint."""
    assert gazereg_main(["priors", *argv(store)]) == 0
    assert gazereg_main(["priors", *argv(store, "--aggregation.past", "6", "--name", "other")]) == 0
    mixed = store.prior_dir("recorded") / "ep_000001.npz"
    shutil.copyfile(store.prior_dir("other") / "ep_000001.npz", mixed)  # the same episode, other settings
    store.read_prior("recorded", 0)
    manifest = store.prior_dir("recorded") / "prior.json"
    with pytest.raises(UsageError) as e:
        store.read_prior("recorded", 1)
    fp, other = (
        store.prior_info("recorded")["settings_fingerprint"],
        store.prior_info("other")["settings_fingerprint"],
    )
    assert fp != other
    assert str(e.value) == (
        f"prior {mixed} was made with other settings (fingerprint {other}) than {manifest} records ({fp}): two "
        "`gazereg priors` runs wrote into 'recorded'; recompute it with `gazereg priors --overwrite`"
    )
    with pytest.raises(
        UsageError, match=rf"prior {mixed} was made with other settings \(fingerprint {other}\)"
    ):
        make_priors(
            PriorsConfig(store=store.root, source="recorded", camera="cam", size=(8, 8)), progress=False
        )
    assert gazereg_main(["priors", *argv(store, "--overwrite")]) == 0
    assert set(files_settings(store, "recorded").values()) == {fp}


def test_the_manifest_records_the_camera_frame_size_and_the_settings_fingerprint(store):
    make_priors(PriorsConfig(store=store.root, source="uniform", camera="cam", size=(8, 8)), progress=False)
    info = store.prior_info("uniform")
    assert info["camera"] == "cam" and info["image_hw"] == [16, 12] and info["size"] == [8, 8]
    assert len(info["settings_fingerprint"]) == 16
    assert set(files_settings(store, "uniform").values()) == {info["settings_fingerprint"]}


def test_priors_made_before_fingerprints_still_read_and_rerun(caplog, store):
    """A manifest and files without the new keys (older priors) are read unchecked and a rerun is a no-op."""
    for i in store.indices():
        T = store.meta(i)["length"]
        store.write_prior("old", i, np.full((T, 8, 8), 1 / 64, np.float32), np.ones(T, bool))
    store.write_prior_info(
        "old",
        {
            "source": {"name": "uniform"},
            "camera": "cam",
            "size": [8, 8],
            "aggregation": dataclasses.asdict(PriorsConfig().aggregation),
        },
    )
    store.read_prior("old", 2)
    cfg = PriorsConfig(store=store.root, source="uniform", name="old", camera="cam", size=(8, 8))
    make_priors(cfg, progress=False)
    assert "settings_fingerprint" not in store.prior_info("old")
    assert "predate settings fingerprints" in caplog.text
