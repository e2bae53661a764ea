"""Priors know the episodes they were made from: a prior from another store is refused, naming both."""

import json
import logging
import os
import shutil

import numpy as np
import pytest
import torch

from gazereg.data.dataset import EpisodeDataset, describe_store, select_episodes
from gazereg.data.store import Episode, EpisodeStore, MissingPriorError, fingerprint_arrays
from gazereg.patches import PatchGeometry
from gazereg.runtime.errors import UsageError


def episode(T=4, level=0, task="reach-v3"):
    rng = np.random.default_rng(level)
    return Episode(
        task=task,
        instruction="reach",
        frames={"front": np.full((T, 8, 8, 3), level, np.uint8)},
        state=rng.standard_normal((T, 3)).astype(np.float32),
        action=rng.standard_normal((T, 2)).astype(np.float32),
        extras={"obj_uv.front": rng.random((T, 2)).astype(np.float32)},
    )


def uniform_prior(store, name, index, size=(4, 4)):
    T = store.meta(index)["length"]
    store.write_prior(name, index, np.full((T, *size), 1 / (size[0] * size[1]), np.float32), np.ones(T, bool))


def two_stores(tmp_path):
    """Stores a and b with episodes of the same lengths but other content; a has the prior 'p'."""
    a, b = EpisodeStore(tmp_path / "a", create=True), EpisodeStore(tmp_path / "b", create=True)
    for k in range(2):
        a.write(episode(T=4 + k, level=k))
        b.write(episode(T=4 + k, level=10 + k))
    for i in a.indices():
        uniform_prior(a, "p", i)
    a.write_prior_info("p", {"camera": "front", "size": [4, 4], "source": {"name": "uniform"}})
    return a, b


def test_fingerprints_identify_the_episode_content(tmp_path):
    store = EpisodeStore(tmp_path / "s", create=True)
    store.write(episode(level=1))
    store.write(episode(level=1))
    store.write(episode(level=2))
    fps = [store.meta(i)["fingerprint"] for i in store.indices()]
    assert fps[0] == fps[1] != fps[2] and len(fps[0]) == 16
    ep = store.read(2)  # what was written, recomputed from the stored arrays
    assert fingerprint_arrays(episode(level=2).stored_arrays(), ep.task, ep.instruction) == fps[2]
    # an episode written before fingerprints gets the same value, computed from its files
    path = store.root / "episodes" / "ep_000002" / "meta.json"
    meta = json.loads(path.read_text())
    del meta["fingerprint"]
    path.write_text(json.dumps(meta))
    assert EpisodeStore(store.root).episode_fingerprint(2) == fps[2]


def test_a_prior_copied_from_another_store_is_refused_naming_both(tmp_path):
    a, b = two_stores(tmp_path)
    heat, valid = a.read_prior("p", 1)  # its own store: fine, values as written
    np.testing.assert_allclose(heat, 1 / 16)
    assert valid.all()
    shutil.copytree(a.prior_dir("p"), b.prior_dir("p"))
    want = b.meta(1)["fingerprint"]
    made = a.meta(1)["fingerprint"]
    with pytest.raises(UsageError) as e:
        b.read_prior("p", 1)
    msg = str(e.value)
    assert str(b.prior_dir("p") / "ep_000001.npz") in msg and made in msg and want in msg
    assert "another store" in msg and "\n" not in msg
    # the training data set refuses it too, before anything trains
    geo = PatchGeometry(input_hw=(8, 8), patch_size=4)

    def tok(texts):
        return torch.zeros(len(texts), 2, dtype=torch.long), torch.ones(len(texts), 2, dtype=torch.bool)

    with pytest.raises(UsageError, match="another store"):
        EpisodeDataset(b, b.indices(), ["front"], 2, tok, gaze_prior="p", geometry=geo)
    ds = EpisodeDataset(a, a.indices(), ["front"], 2, tok, gaze_prior="p", geometry=geo)
    assert ds.gaze.shape == (9, 4)


def test_a_copied_store_keeps_its_priors(tmp_path):
    a, _ = two_stores(tmp_path)
    shutil.copytree(a.root, tmp_path / "copy")
    heat, _ = EpisodeStore(tmp_path / "copy").read_prior("p", 0)
    np.testing.assert_array_equal(heat, a.read_prior("p", 0)[0])


def test_priors_made_before_fingerprints_still_load_with_a_warning(tmp_path, caplog):
    a, _ = two_stores(tmp_path)
    path = a.prior_dir("p") / "ep_000000.npz"
    with np.load(path) as z:
        heat, valid = z["heatmaps"], z["valid"]
    with open(path, "wb") as f:  # an old prior file: no episode fingerprint
        np.savez(f, heatmaps=heat, valid=valid)
    fresh = EpisodeStore(a.root)
    with caplog.at_level(logging.WARNING, logger="gazereg.data.store"):
        h0, _ = fresh.read_prior("p", 0)
        fresh.read_prior("p", 0)
    warnings = [r for r in caplog.records if "predate episode fingerprints" in r.getMessage()]
    assert len(warnings) == 1 and "--overwrite" in warnings[0].getMessage()
    np.testing.assert_allclose(h0, 1 / 16)


def test_unknown_and_incomplete_priors_are_usage_errors(tmp_path):
    a, _ = two_stores(tmp_path)
    with pytest.raises(MissingPriorError, match="no priors named 'x' in .*; it has p$") as e:
        a.prior_info("x")
    assert isinstance(e.value, UsageError) and isinstance(e.value, FileNotFoundError)
    a.write_prior_pending("half", {"camera": "front"})
    uniform_prior(a, "half", 0)
    with pytest.raises(UsageError, match=r"priors 'half' .* are incomplete \(1 of 2 episodes done\)"):
        a.prior_info("half")
    assert a.prior_names() == ["p"] and a.prior_indices("half") == [0]


def test_selection_and_cameras_are_usage_errors(tmp_path):
    a, _ = two_stores(tmp_path)
    with pytest.raises(UsageError, match=r"tasks pick-v3 match none of its tasks \(reach-v3\)"):
        select_episodes(a, ["pick-v3"])
    with pytest.raises(
        UsageError, match="camera 'wrist': episode 0 of store .* has no such camera; it has front"
    ):
        describe_store(a, a.indices(), ["wrist"])


def test_validation_names_the_first_non_finite_row(tmp_path):
    bad = episode(T=5)
    bad.action[3, 1] = np.inf
    with pytest.raises(
        ValueError,
        match=r"'action' must be finite but has 1 NaN/inf value\(s\), the first at row 3, column 1 \(inf\)",
    ):
        EpisodeStore(tmp_path, create=True).write(bad)


def test_store_files_get_ordinary_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        a, _ = two_stores(tmp_path)
    finally:
        os.umask(old)
    ep_dir = a.root / "episodes" / "ep_000000"
    files = [a.root / "store.json", ep_dir / "meta.json", ep_dir / "frames.front.npy"]
    files += [a.prior_dir("p") / "prior.json", a.prior_dir("p") / "ep_000000.npz"]
    assert {f.name: oct(f.stat().st_mode & 0o777) for f in files} == {f.name: "0o644" for f in files}
    assert oct(ep_dir.stat().st_mode & 0o777) == "0o755"
