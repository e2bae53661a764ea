"""LeRobot v3.0 import (fixture written by lerobot 0.6.1) and the priors sidecar export."""

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
from gazereg.data.errors import DataExportError, DataImportError  # noqa: E402
from gazereg.data.export import parse_episode_map  # noqa: E402
from gazereg.data.formats.lerobot_v3 import LeRobotImportConfig, LeRobotV3Dataset, import_lerobot  # noqa: E402
from gazereg.data.formats.lerobot_v3.export import export_priors_lerobot, read_priors_lerobot  # noqa: E402
from gazereg.data.formats.video import VideoFile  # noqa: E402
from gazereg.data.store import EpisodeStore  # noqa: E402
from gazereg.gaze.priors import PriorsConfig, make_priors  # noqa: E402
from gazereg.runtime.errors import UsageError  # noqa: E402

FIXTURE = (
    Path(os.environ.get("GAZEREG_FIXTURES", Path(__file__).resolve().parents[3] / "shared" / "fixtures"))
    / "lerobot_v3_tiny"
)
if not FIXTURE.exists():
    FIXTURE = Path("/work/shared/fixtures/lerobot_v3_tiny")
pytestmark = pytest.mark.skipif(not FIXTURE.exists(), reason="LeRobot v3 fixture not available")

EPISODES_META = "meta/episodes/chunk-000/file-000.parquet"
DATA = "data/chunk-000/file-000.parquet"
VIDEO = "videos/observation.images.front/chunk-000/file-000.mp4"


def expected():
    return json.loads((FIXTURE / "expected.json").read_text())


def cfg(root, out, **kw):
    return LeRobotImportConfig(root=Path(root), out=Path(out), progress=False, **kw)


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    out = tmp_path_factory.mktemp("lerobot") / "store"
    report = import_lerobot(cfg(FIXTURE, out))
    return EpisodeStore(out), report


@pytest.fixture
def copy(tmp_path):
    """A writable copy of the fixture."""
    dst = tmp_path / "ds"
    shutil.copytree(FIXTURE, dst, copy_function=shutil.copyfile)
    for d, _, _ in os.walk(dst):
        os.chmod(d, 0o755)
    return dst


def red_centroid(img):
    a = img.astype(int)
    ys, xs = np.nonzero((a[..., 0] > 150) & (a[..., 1] < 100) & (a[..., 2] < 100))
    assert len(xs) > 50, "no red square"
    return np.array([(xs.mean() + 0.5) / img.shape[1], (ys.mean() + 0.5) / img.shape[0]])


# ----- import ------------------------------------------------------------------------------------------
def test_fixture_import_matches_expected(imported):
    store, report = imported
    assert report["imported"] == 3 and report["frames"] == 66
    assert store.indices() == [0, 1, 2]
    assert [store.meta(i)["length"] for i in store.indices()] == [20, 22, 24]
    exp = expected()
    S = exp["image_size"]
    for f in exp["frames"]:
        ep = store.read(f["episode_index"])
        i, uv = f["frame_index"], np.array(f["square_center_uv"])
        assert ep.task == ep.instruction == f["task"]
        # front (AV1 video): the red square is where expected.json says (AV1 blurs edges: within 2 px)
        assert np.abs(red_centroid(ep.frames["front"][i]) - uv).max() * S < 2.0
        # wrist (PNG in parquet): a green band from x = 0 up to x = u * S (lossless)
        w = ep.frames["wrist"][i].astype(int)
        green_cols = ((w[..., 1] > 150) & (w[..., 0] < 100)).all(axis=0)
        assert abs(green_cols.sum() - uv[0] * S) <= 1.0
        # gaze: stored as recorded gaze of the front camera, and it lands on the red square
        g = ep.extras["gaze_uv.front"][i]
        assert ep.extras["gaze_valid.front"][i]
        np.testing.assert_allclose(g, uv, atol=1e-5)
        x, y = int(g[0] * S), int(g[1] * S)
        r, gch, b = ep.frames["front"][i][y, x].astype(int)
        assert r > 150 and gch < 100 and b < 100
        assert ep.extras["lerobot.frame_index"][i] == i


def test_fixture_metadata_state_action_and_source(imported):
    store, _ = imported
    ep = store.read(1)
    assert ep.state.shape == (22, 4) and ep.action.shape == (22, 4) and ep.state.dtype == np.float32
    assert ep.meta["tasks"] == ["lift the red square"] and ep.meta["fps"] == 10
    assert ep.meta["source"]["format"] == "lerobot_v3" and ep.meta["source"]["episode_index"] == 1
    assert ep.meta["gaze"] == {"camera": "front", "key": "gaze.point"}
    np.testing.assert_array_equal(ep.extras["lerobot.index"], np.arange(20, 42))
    data = pq.read_table(FIXTURE / DATA).to_pydict()
    rows = [k for k, e in enumerate(data["episode_index"]) if e == 1]
    np.testing.assert_allclose(ep.state, np.array([data["observation.state"][k] for k in rows], np.float32))
    np.testing.assert_allclose(ep.action, np.array([data["action"][k] for k in rows], np.float32))


def test_gaze_camera_option_and_camera_subset(tmp_path):
    store_dir = tmp_path / "s"
    import_lerobot(cfg(FIXTURE, store_dir, gaze_camera="wrist", cameras=("wrist",), episodes=(2,)))
    store = EpisodeStore(store_dir)
    assert store.indices() == [2]
    ep = store.read(2)
    assert list(ep.frames) == ["wrist"] and "gaze_uv.wrist" in ep.extras and "gaze_uv.front" not in ep.extras
    with pytest.raises(DataImportError, match="no camera"):
        import_lerobot(cfg(FIXTURE, tmp_path / "t", cameras=("top",)))


def test_rotate180_turns_frames_and_gaze(imported, tmp_path):
    store, _ = imported
    import_lerobot(cfg(FIXTURE, tmp_path / "r", rotate180="front", episodes=(0,)))
    rot = EpisodeStore(tmp_path / "r").read(0)
    ref = store.read(0)
    np.testing.assert_array_equal(rot.frames["front"], ref.frames["front"][:, ::-1, ::-1])
    np.testing.assert_array_equal(rot.frames["wrist"], ref.frames["wrist"])
    np.testing.assert_allclose(rot.extras["gaze_uv.front"], 1 - ref.extras["gaze_uv.front"], atol=1e-6)
    assert rot.meta["orientation_applied"] == {"front": "rot180"}
    assert np.abs(red_centroid(rot.frames["front"][5]) - rot.extras["gaze_uv.front"][5]).max() * 64 < 2.0


def test_resume_skips_done_episodes_and_refuses_other_settings(tmp_path):
    out = tmp_path / "s"
    r1 = import_lerobot(cfg(FIXTURE, out, episodes=(1,)))
    assert r1["imported"] == 1
    r2 = import_lerobot(cfg(FIXTURE, out))
    assert (r2["imported"], r2["skipped"], r2["frames"]) == (2, 1, 44)
    r3 = import_lerobot(cfg(FIXTURE, out))
    assert (r3["imported"], r3["skipped"]) == (0, 3)
    with pytest.raises(DataImportError, match="already holds episode 0 .*other import settings"):
        import_lerobot(cfg(FIXTURE, out, gaze_camera="wrist"))


def test_video_reader_seeks_back_and_forth():
    with VideoFile(FIXTURE / VIDEO) as v:
        late = v.read(4.2 + np.arange(24) / 10)
        early = v.read(np.arange(20) / 10)  # backwards: seeks
        again = v.read(4.2 + np.arange(24) / 10)
        mid = v.read(np.array([5.0, 5.1]))  # inside the previous segment: seeks back
    np.testing.assert_array_equal(late, again)
    np.testing.assert_array_equal(mid, late[8:10])
    assert early.shape == (20, 64, 64, 3)


# ----- corrupt and inconsistent inputs -----------------------------------------------------------------
def _assert_no_partial(store_dir, expected_indices):
    if not expected_indices:  # a first import that wrote no episode leaves no store behind
        assert not Path(store_dir).exists()
        return
    store = EpisodeStore(store_dir)
    assert store.indices() == expected_indices
    leftovers = [p.name for p in (Path(store_dir) / "episodes").iterdir() if p.name.startswith(".")]
    assert leftovers == []


def test_truncated_data_parquet(copy, tmp_path):
    p = copy / DATA
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    with pytest.raises(DataImportError, match=r"data/chunk-000/file-000\.parquet could not be read.*") as ei:
        import_lerobot(cfg(copy, tmp_path / "s"))
    assert "episode 0" in str(ei.value)
    _assert_no_partial(tmp_path / "s", [])


def test_wrong_length_in_metadata(copy, tmp_path):
    t = pq.read_table(copy / EPISODES_META)
    lengths = t.column("length").to_pylist()
    lengths[2] = 23
    t = t.set_column(t.column_names.index("length"), "length", pa.array(lengths, pa.int64()))
    pq.write_table(t, copy / EPISODES_META)
    with pytest.raises(
        DataImportError,
        match=r"file-000\.parquet, episode 2: 24 frames in the data file but the episode metadata says length 23",
    ):
        import_lerobot(cfg(copy, tmp_path / "s"))
    _assert_no_partial(tmp_path / "s", [0, 1])  # earlier episodes are complete; nothing of episode 2


def test_missing_video_camera(copy, tmp_path):
    (copy / VIDEO).unlink()
    with pytest.raises(
        DataImportError,
        match=r"episode 0: video of camera 'front' .* is missing: .*file-000\.mp4 does not exist",
    ):
        import_lerobot(cfg(copy, tmp_path / "s"))
    _assert_no_partial(tmp_path / "s", [])


def test_missing_image_column(copy, tmp_path):
    t = pq.read_table(copy / DATA)
    pq.write_table(t.drop_columns(["observation.images.wrist"]), copy / DATA)
    with pytest.raises(
        DataImportError,
        match=r"episode 0: camera 'wrist' \(observation\.images\.wrist\) is missing from the data file",
    ):
        import_lerobot(cfg(copy, tmp_path / "s"))
    _assert_no_partial(tmp_path / "s", [])


def test_undecodable_video(copy, tmp_path):
    p = copy / VIDEO
    data = bytearray(p.read_bytes())
    p.write_bytes(bytes(data[: len(data) // 3]))
    with pytest.raises(DataImportError, match=r"episode \d, camera 'front': video file .*file-000\.mp4"):
        import_lerobot(cfg(copy, tmp_path / "s"))
    # whatever decoded before the damage was imported whole; the damaged episode left nothing (and no store
    # when it was the first)
    if (tmp_path / "s").exists():
        store = EpisodeStore(tmp_path / "s")
        assert 2 not in store and store.indices()
        _assert_no_partial(tmp_path / "s", store.indices())


def test_timestamps_outside_segment(copy, tmp_path):
    t = pq.read_table(copy / EPISODES_META)
    col = "videos/observation.images.front/from_timestamp"
    ts = t.column(col).to_pylist()
    ts[1] = 3.0
    t = t.set_column(t.column_names.index(col), col, pa.array(ts, pa.float64()))
    pq.write_table(t, copy / EPISODES_META)
    with pytest.raises(DataImportError, match="episode 1"):
        import_lerobot(cfg(copy, tmp_path / "s"))
    _assert_no_partial(tmp_path / "s", [0])


def test_not_a_v3_dataset(copy, tmp_path):
    info = json.loads((copy / "meta/info.json").read_text())
    info["codebase_version"] = "v2.1"
    (copy / "meta/info.json").write_text(json.dumps(info))
    with pytest.raises(DataImportError, match="only LeRobot v3"):
        LeRobotV3Dataset(copy)
    with pytest.raises(DataImportError, match="not a LeRobot data set"):
        LeRobotV3Dataset(tmp_path)


# ----- priors sidecar ----------------------------------------------------------------------------------
def _recorded_priors(store_dir, camera="front"):
    make_priors(
        PriorsConfig(
            store=Path(store_dir),
            source="recorded",
            camera=camera,
            size=(16, 16),
            aggregation=AggregationConfig(past=0, future=0),
        ),
        progress=False,
    )
    return "recorded"


def test_export_priors_round_trip(tmp_path):
    out = tmp_path / "s"
    import_lerobot(cfg(FIXTURE, out))
    name = _recorded_priors(out)
    store = EpisodeStore(out)
    path = export_priors_lerobot(store, name, tmp_path / "sidecar")
    assert path == tmp_path / "sidecar" / "priors.parquet"
    info = json.loads((tmp_path / "sidecar" / "priors.json").read_text())
    assert info["shape"] == [16, 16] and info["camera"] == "front" and info["num_frames"] == 66
    t = pq.read_table(path)
    assert t.column_names == ["episode_index", "frame_index", "index", "prior", "valid"]
    assert t.schema.field("prior").type == pa.list_(pa.float32(), 256)
    sc = read_priors_lerobot(tmp_path / "sidecar")
    data = pq.read_table(FIXTURE / DATA, columns=["episode_index", "frame_index", "index"]).to_pydict()
    np.testing.assert_array_equal(sc.index, data["index"])
    np.testing.assert_array_equal(sc.episode_index, data["episode_index"])
    for e in (0, 1, 2):
        heat, valid = store.read_prior(name, e)
        for f in (0, 7, len(valid) - 1):
            got, ok = sc.get(e, f)
            np.testing.assert_allclose(got, heat[f], atol=1e-7)
            assert ok == valid[f]
    # the prior's peak lies on the red square of the dataset frame
    heat, _ = sc.get(2, 10)
    r, c = np.unravel_index(heat.argmax(), heat.shape)
    uv = np.array([(c + 0.5) / 16, (r + 0.5) / 16])
    exp = next(f for f in expected()["frames"] if f["episode_index"] == 2 and f["frame_index"] == 10)
    assert np.abs(uv - exp["square_center_uv"]).max() < 1 / 16 + 1e-6


def test_export_undoes_import_rotation_and_episode_map(tmp_path):
    plain, rot = tmp_path / "plain", tmp_path / "rot"
    import_lerobot(cfg(FIXTURE, plain, episodes=(0,)))
    import_lerobot(cfg(FIXTURE, rot, episodes=(0,), rotate180="front"))
    for s in (plain, rot):
        _recorded_priors(s)
    a = read_priors_lerobot(export_priors_lerobot(plain, "recorded", tmp_path / "a"))
    b = read_priors_lerobot(export_priors_lerobot(rot, "recorded", tmp_path / "b"))
    np.testing.assert_allclose(a.priors, b.priors, atol=1e-6)
    m = read_priors_lerobot(export_priors_lerobot(plain, "recorded", tmp_path / "m", episode_map={0: 7}))
    assert set(m.episode_index.tolist()) == {7}
    with pytest.raises(UsageError, match="no priors named 'nope'"):
        export_priors_lerobot(plain, "nope", tmp_path / "x")
    with pytest.raises(DataExportError, match="no 'recorded' priors to export for the given episode map"):
        export_priors_lerobot(plain, "recorded", tmp_path / "d", episode_map={5: 7})
    assert parse_episode_map(("0=7", "2=9")) == {0: 7, 2: 9} and parse_episode_map(()) is None
    with pytest.raises(DataExportError, match="store_index=episode_index"):
        parse_episode_map(("0:7",))


# ----- CLI ---------------------------------------------------------------------------------------------
def test_cli_import_and_export(tmp_path, capsys):
    out = tmp_path / "s"
    assert (
        data_cli.main(
            [
                "lerobot",
                "--root",
                str(FIXTURE),
                "--out",
                str(out),
                "--gaze-camera",
                "front",
                "--episodes",
                "0",
                "--no-progress",
            ]
        )
        == 0
    )
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["imported"] == 1
    _recorded_priors(out)
    assert (
        data_cli.main(
            ["export-priors", "--store", str(out), "--prior", "recorded", "--out", str(tmp_path / "x")]
        )
        == 0
    )
    assert (tmp_path / "x" / "priors.json").exists()
    capsys.readouterr()
    missing = ["import", "lerobot", "--root", str(tmp_path / "missing"), "--out", str(out)]
    assert gazereg_main(missing) == 2  # a wrong path is a usage mistake (the top-level CLI reports it)
    err = capsys.readouterr().err
    assert (
        err.startswith("gazereg import: error: ") and "not a LeRobot data set" in err and err.count("\n") == 1
    )
    bad_map = ["import", "export-priors", "--store", str(out), "--prior", "recorded", "--episode-map", "0:7"]
    assert gazereg_main([*bad_map, "--out", str(tmp_path / "y")]) == 2
    assert "store_index=episode_index" in capsys.readouterr().err
    assert data_cli.main(["nope"]) == 2
    assert data_cli.main(["--help"]) == 0


# ----- a synthetic data set: H.264, episodes spread over two video files ---------------------------------
def write_v3_tables(root, rows, ep_rows, hw, fps):
    """write_synthetic_v3's parquet tables (frames, episodes, tasks) and meta/info.json."""
    vec = pa.list_(pa.float32(), 2)
    pq.write_table(
        pa.table(
            {
                "observation.state": pa.array([r["observation.state"] for r in rows], vec),
                "action": pa.array([r["action"] for r in rows], vec),
                "timestamp": pa.array([r["timestamp"] for r in rows], pa.float32()),
                **{
                    k: pa.array([r[k] for r in rows], pa.int64())
                    for k in ("frame_index", "episode_index", "index", "task_index")
                },
            }
        ),
        root / "data/chunk-000/file-000.parquet",
    )
    pq.write_table(pa.Table.from_pylist(ep_rows), root / "meta/episodes/chunk-000/file-000.parquet")
    pq.write_table(
        pa.table({"task_index": [0, 1], "task": ["task 0", "task 1"]}), root / "meta/tasks.parquet"
    )
    feats = {
        "observation.images.top": {
            "dtype": "video",
            "shape": [*hw, 3],
            "names": ["height", "width", "channels"],
            "info": {"video.codec": "h264"},
        },
        "observation.state": {"dtype": "float32", "shape": [2], "names": None},
        "action": {"dtype": "float32", "shape": [2], "names": None},
        **{
            k: {"dtype": "int64", "shape": [1], "names": None}
            for k in ("frame_index", "episode_index", "index", "task_index")
        },
        "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    }
    (root / "meta/info.json").write_text(
        json.dumps(
            {
                "codebase_version": "v3.0",
                "fps": fps,
                "features": feats,
                "total_episodes": len(ep_rows),
                "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
                "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
            }
        )
    )


def write_synthetic_v3(root, lengths=(6, 7, 5), files=(0, 0, 1), fps=10, hw=(32, 32)):
    """A minimal LeRobot v3.0 data set: camera `observation.images.top` (H.264), frame (e, i) is uniform grey
    at level 30 + 60 * e + 5 * i; state = (e, i), action = (i, -i)."""
    import av

    root = Path(root)
    (root / "meta/episodes/chunk-000").mkdir(parents=True)
    (root / "data/chunk-000").mkdir(parents=True)
    vdir = root / "videos/observation.images.top/chunk-000"
    vdir.mkdir(parents=True)
    writers, clock, rows, ep_rows, g = {}, {}, [], [], 0
    for e, (T, f) in enumerate(zip(lengths, files)):
        if f not in writers:
            c = av.open(str(vdir / f"file-{f:03d}.mp4"), "w")
            s = c.add_stream("libx264", rate=fps)
            s.width, s.height, s.pix_fmt = hw[1], hw[0], "yuv420p"
            s.options = {"g": "3", "bf": "2", "crf": "10"}
            writers[f], clock[f] = (c, s), 0
        c, s = writers[f]
        start = clock[f]
        for i in range(T):
            img = np.full((*hw, 3), 30 + 60 * e + 5 * i, np.uint8)
            fr = av.VideoFrame.from_ndarray(img, format="rgb24")
            fr.pts = start + i
            for p in s.encode(fr):
                c.mux(p)
            rows.append(
                {
                    "observation.state": [float(e), float(i)],
                    "action": [float(i), float(-i)],
                    "timestamp": i / fps,
                    "frame_index": i,
                    "episode_index": e,
                    "index": g,
                    "task_index": e % 2,
                }
            )
            g += 1
        clock[f] = start + T
        ep_rows.append(
            {
                "episode_index": e,
                "tasks": [f"task {e % 2}"],
                "length": T,
                "data/chunk_index": 0,
                "data/file_index": 0,
                "dataset_from_index": g - T,
                "dataset_to_index": g,
                "videos/observation.images.top/chunk_index": 0,
                "videos/observation.images.top/file_index": f,
                "videos/observation.images.top/from_timestamp": start / fps,
                "videos/observation.images.top/to_timestamp": (start + T) / fps,
            }
        )
    for c, s in writers.values():
        for p in s.encode():
            c.mux(p)
        c.close()
    write_v3_tables(root, rows, ep_rows, hw, fps)
    return root


def test_h264_several_files_any_order(tmp_path):
    root = write_synthetic_v3(tmp_path / "ds")
    report = import_lerobot(cfg(root, tmp_path / "s", episodes=(2, 0, 1)))
    assert report["imported"] == 3
    store = EpisodeStore(tmp_path / "s")
    for e, T in enumerate((6, 7, 5)):
        ep = store.read(e)
        assert ep.length == T and list(ep.frames) == ["top"] and ep.task == f"task {e % 2}"
        levels = ep.frames["top"].reshape(T, -1).mean(axis=1)
        np.testing.assert_allclose(levels, 30 + 60 * e + 5 * np.arange(T), atol=2.0)
        np.testing.assert_array_equal(ep.state, np.stack([np.full(T, e), np.arange(T)], 1))
        assert "gaze_uv.top" not in ep.extras


def test_non_finite_state_is_refused_by_name(copy, tmp_path):
    t = pq.read_table(copy / DATA)
    states = t.column("observation.state").to_pylist()
    states[25][0] = float("nan")  # episode 1, frame 5
    col = pa.array(states, t.schema.field("observation.state").type)
    t = t.set_column(t.column_names.index("observation.state"), "observation.state", col)
    pq.write_table(t, copy / DATA)
    with pytest.raises(
        DataImportError,
        match=r"/ds: episode 1: 'state' must be finite but has 1 NaN/inf value\(s\), the first at row 5, column 0 \(nan\)",
    ):
        import_lerobot(cfg(copy, tmp_path / "s"))
    _assert_no_partial(tmp_path / "s", [0])


def test_camera_names_and_image_shapes():
    from gazereg.data.formats.lerobot_v3.metadata import camera_name, image_hw, rgb_cameras

    assert camera_name("observation.images.front") == "front"
    assert camera_name("observation.image.wrist/left") == "wrist_left"
    assert camera_name("observation.images.") == "images."
    assert image_hw({"shape": [48, 64, 3], "names": ["height", "width", "channels"]}) == (48, 64)
    assert image_hw({"shape": [3, 48, 64], "names": ["channels", "height", "width"]}) == (48, 64)
    assert image_hw({"shape": [3, 48, 64]}) == (48, 64)
    assert image_hw({"shape": [48]}) is None
    features = {
        "observation.images.front": {"dtype": "video", "shape": [48, 64, 3]},
        "observation.images.depth": {"dtype": "video", "shape": [48, 64, 1]},
        "observation.images.ir": {"dtype": "image", "shape": [48, 64, 3], "info": {"is_depth_map": True}},
        "observation.images.wrist": {"dtype": "image", "shape": [3, 48, 64]},
        "action": {"dtype": "float32", "shape": [7]},
    }
    assert rgb_cameras(features) == {"front": "observation.images.front", "wrist": "observation.images.wrist"}
