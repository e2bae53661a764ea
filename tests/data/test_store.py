import numpy as np
import pytest

from gazereg.data.store import Episode, EpisodeStore


def make_episode(T=5, cams=("front",), hw=(8, 8), task="reach-v3"):
    rng = np.random.default_rng(T)
    return Episode(
        task=task,
        instruction="reach the goal",
        frames={c: rng.integers(0, 255, (T, *hw, 3), dtype=np.uint8) for c in cams},
        state=rng.standard_normal((T, 4)).astype(np.float32),
        action=rng.standard_normal((T, 4)).astype(np.float32),
        extras={"obj_uv.front": rng.random((T, 2)).astype(np.float32)},
        meta={"seed": 3, "success": True},
    )


def test_write_read_round_trip(tmp_path):
    store = EpisodeStore(tmp_path / "s", create=True)
    ep = make_episode()
    assert store.write(ep) == 0 and store.write(make_episode(T=3)) == 1
    again = EpisodeStore(tmp_path / "s")
    assert again.indices() == [0, 1] and len(again) == 2 and 1 in again
    r = again.read(0)
    np.testing.assert_array_equal(r.frames["front"], ep.frames["front"])
    np.testing.assert_array_equal(r.extras["obj_uv.front"], ep.extras["obj_uv.front"])
    assert r.instruction == "reach the goal" and r.meta["seed"] == 3 and r.length == 5
    assert isinstance(r.frames["front"], np.memmap)


def test_inconsistent_episodes_are_rejected_without_leaving_files(tmp_path):
    store = EpisodeStore(tmp_path, create=True)
    bad = make_episode()
    bad.state = bad.state[:3]
    with pytest.raises(ValueError, match="'state' has 3 rows"):
        store.write(bad)
    empty = make_episode(T=0)
    with pytest.raises(ValueError, match="empty"):
        store.write(empty)
    assert store.indices() == []
    assert list((tmp_path / "episodes").iterdir()) == []


def test_failed_write_leaves_no_partial_episode(tmp_path, monkeypatch):
    store = EpisodeStore(tmp_path, create=True)
    calls = {"n": 0}
    real_save = np.save

    def flaky_save(*a, **k):
        calls["n"] += 1
        if calls["n"] == 2:
            raise OSError("disk full")
        return real_save(*a, **k)

    monkeypatch.setattr(np, "save", flaky_save)
    with pytest.raises(OSError):
        store.write(make_episode())
    monkeypatch.undo()
    assert store.indices() == [] and list((tmp_path / "episodes").iterdir()) == []


def test_priors_round_trip_and_validation(tmp_path):
    store = EpisodeStore(tmp_path, create=True)
    store.write(make_episode(T=4))
    heat = np.random.default_rng(0).random((4, 6, 6)).astype(np.float32)
    heat /= heat.sum((1, 2), keepdims=True)
    valid = np.array([True, True, False, True])
    store.write_prior_info("vm", {"source": "visuomotor", "camera": "front"})
    store.write_prior("vm", 0, heat, valid)
    h, v = store.read_prior("vm", 0)
    np.testing.assert_allclose(h[valid], heat[valid], atol=2e-3)
    np.testing.assert_allclose(h[valid].sum((1, 2)), 1.0, atol=1e-6)
    assert store.prior_names() == ["vm"] and store.has_prior("vm", 0)
    with pytest.raises(ValueError, match="T=4"):
        store.write_prior("vm", 0, heat[:3], valid[:3])
    heat[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        store.write_prior("vm", 0, heat, valid)
    with pytest.raises(FileNotFoundError, match="no priors named 'x'"):
        store.prior_info("x")


def test_not_a_store(tmp_path):
    with pytest.raises(FileNotFoundError, match="not an episode store"):
        EpisodeStore(tmp_path / "nothing")
