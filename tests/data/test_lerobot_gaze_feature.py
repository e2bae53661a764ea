"""`gazereg import write-gaze`: a store's priors as gaze.<camera>.heatmap / .valid features of a new LeRobot v3
data set version (the real-lerobot side is tests_lerobot/test_gaze_feature.py)."""

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("av")
pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

from gazereg.aggregation import AggregationConfig  # noqa: E402
from gazereg.cli import main as gazereg_main  # noqa: E402
from gazereg.data import cli as data_cli  # noqa: E402
from gazereg.data.formats.lerobot_v3 import LeRobotImportConfig, LeRobotV3Dataset, import_lerobot  # noqa: E402
from gazereg.data.formats.lerobot_v3.gaze_feature import resize_maps, write_gaze_dataset  # noqa: E402
from gazereg.data.store import EpisodeStore  # noqa: E402
from gazereg.gaze.priors import PriorsConfig, make_priors  # noqa: E402
from gazereg.runtime.errors import UsageError  # noqa: E402

FIXTURE = Path(os.environ.get("GAZEREG_FIXTURES", "/work/shared/fixtures")) / "lerobot_v3_tiny"
pytestmark = pytest.mark.skipif(not FIXTURE.exists(), reason="LeRobot v3 fixture not available")
HEAT, VALID = "gaze.front.heatmap", "gaze.front.valid"


def _store(tmp, rotate180="none", episodes=(), past=1):
    """The fixture imported into a store with `recorded` priors of the front camera (16x16, aggregated)."""
    out = Path(tmp)
    import_lerobot(
        LeRobotImportConfig(root=FIXTURE, out=out, progress=False, rotate180=rotate180, episodes=episodes)
    )
    agg = AggregationConfig(past=past, future=0)
    make_priors(
        PriorsConfig(store=out, source="recorded", camera="front", size=(16, 16), aggregation=agg),
        progress=False,
    )
    return EpisodeStore(out)


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("gaze_feature")
    store = _store(tmp / "store")
    report = write_gaze_dataset(store, "recorded", FIXTURE, tmp / "v2")
    return store, tmp / "v2", report


def test_new_version_holds_the_prior_as_features(written):
    store, out, report = written
    assert report["heatmap_key"] == HEAT and report["valid_key"] == VALID and report["shape"] == [16, 16]
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["features"][HEAT] == {"dtype": "float32", "shape": [16, 16], "names": ["height", "width"]}
    assert info["features"][VALID] == {"dtype": "bool", "shape": [1], "names": None}
    src_info = json.loads((FIXTURE / "meta" / "info.json").read_text())
    assert {k: v for k, v in info["features"].items() if k not in (HEAT, VALID)} == src_info["features"]
    # our own reader sees the new columns; every frame equals the store's prior for that frame
    ds = LeRobotV3Dataset(out)
    assert HEAT in ds.features and ds.cameras == LeRobotV3Dataset(FIXTURE).cameras
    t = pq.read_table(out / "data/chunk-000/file-000.parquet")
    assert (
        t.schema.field(HEAT).type == pa.list_(pa.list_(pa.float32()))
        and t.schema.field(VALID).type == pa.bool_()
    )
    hf = json.loads(t.schema.metadata[b"huggingface"])["info"]["features"]
    assert hf[HEAT] == {"shape": [16, 16], "dtype": "float32", "_type": "Array2D"}
    heat = np.asarray(t.column(HEAT).to_pylist(), np.float32)
    valid = t.column(VALID).to_numpy(zero_copy_only=False)
    ep_col, fr_col = t.column("episode_index").to_numpy(), t.column("frame_index").to_numpy()
    for e in (0, 1, 2):
        prior, ok = store.read_prior("recorded", e)
        rows = np.nonzero(ep_col == e)[0]
        np.testing.assert_allclose(heat[rows], prior[fr_col[rows]], atol=1e-7)
        np.testing.assert_array_equal(valid[rows], ok[fr_col[rows]])
    assert valid.all() and np.allclose(heat.sum((1, 2)), 1, atol=1e-5)
    # the store reads the unchanged columns back as before (the new version is still a LeRobot data set)
    ep = ds.read_episode(1)
    np.testing.assert_array_equal(ep.extras["lerobot.index"], np.arange(20, 42))
    assert ep.extras[HEAT].shape == (22, 16, 16)


def test_stats_videos_and_source_untouched(written):
    store, out, _ = written
    stats = json.loads((out / "meta" / "stats.json").read_text())
    heat = np.asarray(pq.read_table(out / "data/chunk-000/file-000.parquet").column(HEAT).to_pylist())
    np.testing.assert_allclose(stats[HEAT]["mean"], heat.mean(0), atol=1e-9)
    np.testing.assert_allclose(stats[HEAT]["max"], heat.max(0))
    assert stats[HEAT]["count"] == [66] and np.shape(stats[HEAT]["q50"]) == (16, 16)
    assert stats[VALID]["mean"] == [1.0] and stats[VALID]["count"] == [66]
    assert stats["action"] == json.loads((FIXTURE / "meta" / "stats.json").read_text())["action"]
    eps = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pydict()
    assert eps[f"stats/{HEAT}/count"] == [[20], [22], [24]]
    assert np.shape(eps[f"stats/{HEAT}/mean"][0]) == (16, 16)
    video = "videos/observation.images.front/chunk-000/file-000.mp4"
    assert (out / video).read_bytes() == (FIXTURE / video).read_bytes()
    assert "gaze.front.heatmap" not in (FIXTURE / "meta" / "info.json").read_text()
    assert (out / "meta" / "tasks.parquet").exists() and not list(out.parent.glob("*.tmp"))


def test_rotation_undone_resize_and_partial_store(tmp_path):
    """A store imported with the front camera turned gets its maps turned back; a store holding one episode
    leaves the others invalid (zero maps); --size resizes each map keeping mass 1."""
    plain = _store(tmp_path / "a", episodes=(0,), past=0)
    rot = _store(tmp_path / "b", episodes=(0,), rotate180="front", past=0)
    write_gaze_dataset(plain, "recorded", FIXTURE, tmp_path / "pa")
    write_gaze_dataset(rot, "recorded", FIXTURE, tmp_path / "pb")
    a = pq.read_table(tmp_path / "pa/data/chunk-000/file-000.parquet")
    b = pq.read_table(tmp_path / "pb/data/chunk-000/file-000.parquet")
    np.testing.assert_allclose(
        np.asarray(a.column(HEAT).to_pylist()), np.asarray(b.column(HEAT).to_pylist()), atol=1e-6
    )
    valid = a.column(VALID).to_numpy(zero_copy_only=False)
    ep = a.column("episode_index").to_numpy()
    assert valid[ep == 0].all() and not valid[ep != 0].any()
    r = write_gaze_dataset(plain, "recorded", FIXTURE, tmp_path / "pc", size=(8, 8))
    c = np.asarray(pq.read_table(tmp_path / "pc/data/chunk-000/file-000.parquet").column(HEAT).to_pylist())
    assert r["shape"] == [8, 8] and c.shape == (66, 8, 8)
    np.testing.assert_allclose(c[ep == 0].sum((1, 2)), 1, atol=1e-5)
    heat = np.asarray(a.column(HEAT).to_pylist(), np.float32)[ep == 0]
    np.testing.assert_allclose(c[ep == 0], heat.reshape(-1, 8, 2, 8, 2).sum((2, 4)), atol=1e-6)
    assert resize_maps(np.ones((1, 4, 4)), np.array([False]), (2, 2)).sum() == 0


def test_refuses_other_data_sets_lengths_and_existing_out(written, tmp_path):
    store, out, _ = written
    with pytest.raises(UsageError, match="already exists"):
        write_gaze_dataset(store, "recorded", FIXTURE, out)
    with pytest.raises(UsageError, match="inside the source"):
        write_gaze_dataset(store, "recorded", FIXTURE, FIXTURE / "v2")
    # the new version has other features (another schema): the store was not imported from it
    with pytest.raises(UsageError, match="was not imported from the LeRobot data set"):
        write_gaze_dataset(store, "recorded", out, tmp_path / "x")
    # same schema, other lengths
    ds = tmp_path / "ds"
    shutil.copytree(FIXTURE, ds, copy_function=shutil.copyfile)
    for d, _, _ in os.walk(ds):
        os.chmod(d, 0o755)
    meta = ds / "meta/episodes/chunk-000/file-000.parquet"
    t = pq.read_table(meta)
    t = t.set_column(t.column_names.index("length"), "length", pa.array([20, 21, 24], pa.int64()))
    pq.write_table(t, meta)
    with pytest.raises(UsageError, match=r"episode 1 \(episode_index 1, length 22\) does not match"):
        write_gaze_dataset(store, "recorded", ds, tmp_path / "y")
    with pytest.raises(UsageError, match="no priors named 'nope'"):
        write_gaze_dataset(store, "nope", FIXTURE, tmp_path / "z")
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_cli_write_gaze(written, tmp_path, capsys):
    store, _, _ = written
    argv = ["write-gaze", "--store", str(store.root), "--prior", "recorded", "--root", str(FIXTURE)]
    assert data_cli.main([*argv, "--out", str(tmp_path / "n"), "--size", "4", "4", "--no-progress"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["shape"] == [4, 4] and report["episodes"] == [0, 1, 2] and report["valid_frames"] == 66
    assert gazereg_main(["import", *argv, "--out", str(tmp_path / "n")]) == 2
    err = capsys.readouterr().err
    assert "already exists" in err and err.count("\n") == 1
    assert gazereg_main(["import", *argv, "--out", str(tmp_path / "m"), "--size", "4"]) == 2
