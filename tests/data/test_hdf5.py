"""LIBERO / robomimic HDF5 import: small files written here with h5py."""

import json
from pathlib import Path

import numpy as np
import pytest

h5py = pytest.importorskip("h5py")

from gazereg.cli import main as gazereg_main  # noqa: E402
from gazereg.data import cli as data_cli  # noqa: E402
from gazereg.data.errors import DataImportError, ImportUsageError  # noqa: E402
from gazereg.data.formats.hdf5 import Hdf5ImportConfig, import_hdf5  # noqa: E402
from gazereg.data.formats.hdf5.demos import instruction_from_filename  # noqa: E402
from gazereg.data.store import EpisodeStore  # noqa: E402

HW = (24, 32)
MARK = (3, 5)  # (row, col) of the bright marker in the raw (upside-down) agentview image
INSTRUCTION = "put the bowl on the plate"


def raw_agentview(T, d):
    img = np.full((T, *HW, 3), 40 + d, np.uint8)
    img[:, MARK[0], MARK[1]] = (250, 10, 10)
    return img


def write_libero(path, lengths=(5, 6, 7), gaze=False, libero=True):
    """LIBERO layout: problem_info in data.attrs, agentview_rgb / eye_in_hand_rgb upside down, proprio obs."""
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        if libero:
            data.attrs["problem_info"] = json.dumps(
                {"problem_name": "libero_tabletop_manipulation", "language_instruction": INSTRUCTION}
            )
            data.attrs["bddl_file_name"] = "put_the_bowl_on_the_plate.bddl"
        for d, T in enumerate(lengths):
            g = data.create_group(f"demo_{d}")
            g.attrs["num_samples"] = T
            g["actions"] = np.arange(T * 7, dtype=np.float64).reshape(T, 7) + d
            g["states"] = np.full((T, 20), d, np.float64)
            g["rewards"] = np.zeros(T)
            g["dones"] = np.zeros(T, np.uint8)
            obs = g.create_group("obs")
            obs["agentview_rgb"] = raw_agentview(T, d)
            obs["eye_in_hand_rgb"] = np.tile(
                np.arange(HW[1], dtype=np.uint8)[None, None, :, None], (T, HW[0], 1, 3)
            )
            obs["ee_pos"] = np.ones((T, 3)) * d
            obs["ee_ori"] = np.ones((T, 3)) * 2
            obs["gripper_states"] = np.ones((T, 2)) * 3
            obs["joint_states"] = np.ones((T, 7))
            if gaze:
                uv = np.tile([(MARK[1] + 0.5) / HW[1], (MARK[0] + 0.5) / HW[0]], (T, 1))
                uv[1] = np.nan
                obs["gaze_uv"] = uv
    return path


def write_robomimic(path, demos=(1, 2)):
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        data.attrs["env_args"] = json.dumps({"env_name": "Lift", "type": 1})
        for d in demos:
            T = 4 + d
            g = data.create_group(f"demo_{d}")
            g["actions"] = np.zeros((T, 7), np.float32)
            g["states"] = np.zeros((T, 32))
            obs = g.create_group("obs")
            obs["agentview_image"] = raw_agentview(T, d)
            obs["robot0_eef_pos"] = np.ones((T, 3))
            obs["robot0_eef_quat"] = np.ones((T, 4))
            obs["robot0_gripper_qpos"] = np.ones((T, 2))
    return path


def cfg(files, out, **kw):
    files = tuple(Path(p) for p in (files if isinstance(files, list | tuple) else [files]))
    return Hdf5ImportConfig(file=files, out=Path(out), progress=False, **kw)


def test_libero_round_trip_with_orientation(tmp_path):
    src = write_libero(tmp_path / "put_the_bowl_on_the_plate_demo.hdf5", gaze=True)
    report = import_hdf5(cfg(src, tmp_path / "s", gaze_key="gaze_uv"))
    assert report["imported"] == 3 and report["frames"] == 18
    store = EpisodeStore(tmp_path / "s")
    assert store.indices() == [0, 1, 2]
    with h5py.File(src) as f:
        for d, T in enumerate((5, 6, 7)):
            ep = store.read(d)
            g = f[f"data/demo_{d}"]
            assert ep.instruction == INSTRUCTION and ep.task == "put_the_bowl_on_the_plate" and ep.length == T
            # upright: both LIBERO cameras turned by 180 degrees, bit-exact
            np.testing.assert_array_equal(
                ep.frames["agentview_rgb"], g["obs/agentview_rgb"][()][:, ::-1, ::-1]
            )
            np.testing.assert_array_equal(
                ep.frames["eye_in_hand_rgb"], g["obs/eye_in_hand_rgb"][()][:, ::-1, ::-1]
            )
            r, c = HW[0] - 1 - MARK[0], HW[1] - 1 - MARK[1]
            assert tuple(ep.frames["agentview_rgb"][0, r, c]) == (250, 10, 10)
            # the gaze follows the frames: it still lands on the marker
            uv = ep.extras["gaze_uv.agentview_rgb"]
            assert not ep.extras["gaze_valid.agentview_rgb"][1] and np.isnan(uv[1]).all()
            assert int(uv[0, 0] * HW[1]) == c and int(uv[0, 1] * HW[0]) == r
            assert ep.meta["orientation_applied"] == {"agentview_rgb": "rot180", "eye_in_hand_rgb": "rot180"}
            # state = ee_pos + ee_ori + gripper_states (8-d); the rest kept as extras
            np.testing.assert_array_equal(
                ep.state, np.tile(np.array([d] * 3 + [2] * 3 + [3] * 2, np.float32), (T, 1))
            )
            np.testing.assert_array_equal(ep.action, g["actions"][()].astype(np.float32))
            np.testing.assert_array_equal(ep.extras["sim_state"], g["states"][()])
            assert ep.extras["obs.joint_states"].shape == (T, 7) and "obs.gaze_uv" not in ep.extras
            assert (
                ep.meta["source"]["demo"] == f"demo_{d}"
                and ep.meta["problem_info"]["language_instruction"] == INSTRUCTION
            )


def test_robomimic_defaults_and_overrides(tmp_path):
    src = write_robomimic(tmp_path / "lift_ph_demo.hdf5")
    import_hdf5(cfg(src, tmp_path / "s"))
    store = EpisodeStore(tmp_path / "s")
    assert store.indices() == [1, 2]  # demo numbers are the store indices
    ep = store.read(1)
    np.testing.assert_array_equal(ep.frames["agentview_image"], raw_agentview(5, 1))  # not LIBERO: untouched
    assert "orientation_applied" not in ep.meta and ep.meta["env_name"] == "Lift"
    assert ep.instruction == "lift ph" and ep.state.shape == (5, 9)
    # explicit rotation, instruction, state
    import_hdf5(
        cfg(
            src,
            tmp_path / "t",
            rotate180="agentview_image",
            instruction="lift the cube",
            state_keys=("states",),
        )
    )
    ep = EpisodeStore(tmp_path / "t").read(2)
    np.testing.assert_array_equal(ep.frames["agentview_image"], raw_agentview(6, 2)[:, ::-1, ::-1])
    assert ep.instruction == "lift the cube" and ep.state.shape == (6, 32)
    # LIBERO file with rotation switched off
    lib = write_libero(tmp_path / "libero.hdf5")
    import_hdf5(cfg(lib, tmp_path / "u", rotate180="none"))
    np.testing.assert_array_equal(
        EpisodeStore(tmp_path / "u").read(0).frames["agentview_rgb"], raw_agentview(5, 0)
    )


def test_instruction_from_filename():
    assert instruction_from_filename("KITCHEN_SCENE3_turn_on_the_stove_demo.hdf5") == "turn on the stove"
    assert instruction_from_filename("/x/pick_up_the_black_bowl_demo.hdf5") == "pick up the black bowl"


def test_several_files_get_disjoint_indices_and_resume(tmp_path):
    a = write_libero(tmp_path / "a_demo.hdf5", lengths=(3, 4))
    b = write_robomimic(tmp_path / "b_demo.hdf5", demos=(0, 1, 2))
    r1 = import_hdf5(cfg([a, b], tmp_path / "s", rotate180="none"))
    store = EpisodeStore(tmp_path / "s")
    assert r1["imported"] == 5 and store.indices() == [0, 1, 2, 3, 4]
    assert store.meta(2)["source"]["file"] == "b_demo.hdf5" and store.meta(2)["source"]["demo"] == "demo_0"
    r2 = import_hdf5(cfg([a, b], tmp_path / "s", rotate180="none"))
    assert (r2["imported"], r2["skipped"]) == (0, 5)
    with pytest.raises(DataImportError, match="already holds episode 0"):
        import_hdf5(cfg([b, a], tmp_path / "s", rotate180="none"))


def _assert_no_partial(store_dir, indices):
    assert EpisodeStore(store_dir).indices() == indices
    assert [p.name for p in (Path(store_dir) / "episodes").iterdir() if p.name.startswith(".")] == []


def test_wrong_length_names_file_and_demo_and_leaves_nothing(tmp_path):
    src = write_libero(tmp_path / "bad_demo.hdf5")
    with h5py.File(src, "a") as f:
        del f["data/demo_1/obs/eye_in_hand_rgb"]
        f["data/demo_1/obs/eye_in_hand_rgb"] = np.zeros((4, *HW, 3), np.uint8)
    with pytest.raises(
        DataImportError,
        match=r"bad_demo\.hdf5, demo_1: 'eye_in_hand_rgb' has 4 rows but the demo has 6 actions",
    ):
        import_hdf5(cfg(src, tmp_path / "s"))
    _assert_no_partial(tmp_path / "s", [0])
    # after fixing the file, the import resumes from demo_1
    with h5py.File(src, "a") as f:
        del f["data/demo_1/obs/eye_in_hand_rgb"]
        f["data/demo_1/obs/eye_in_hand_rgb"] = np.zeros((6, *HW, 3), np.uint8)
    r = import_hdf5(cfg(src, tmp_path / "s"))
    assert (r["imported"], r["skipped"]) == (2, 1)


def test_missing_camera_and_corrupt_files(tmp_path):
    src = write_libero(tmp_path / "x_demo.hdf5")
    with h5py.File(src, "a") as f:
        del f["data/demo_2/obs/agentview_rgb"]
    with pytest.raises(DataImportError, match=r"x_demo\.hdf5, demo_2: camera 'agentview_rgb' is missing"):
        import_hdf5(cfg(src, tmp_path / "s"))
    _assert_no_partial(tmp_path / "s", [0, 1])
    with pytest.raises(DataImportError, match="rotate180 names camera"):
        import_hdf5(cfg(src, tmp_path / "t", rotate180="top"))
    trunc = tmp_path / "trunc_demo.hdf5"
    trunc.write_bytes(src.read_bytes()[:2000])
    with pytest.raises(DataImportError, match=r"trunc_demo\.hdf5 could not be opened"):
        import_hdf5(cfg(trunc, tmp_path / "u"))
    with pytest.raises(DataImportError, match="does not exist"):
        import_hdf5(cfg(tmp_path / "nope.hdf5", tmp_path / "u"))
    empty = tmp_path / "empty.hdf5"
    with h5py.File(empty, "w") as f:
        f.create_group("data")
    with pytest.raises(DataImportError, match="no data/demo_<n> groups"):
        import_hdf5(cfg(empty, tmp_path / "u"))


def test_cli(tmp_path, capsys):
    src = write_libero(tmp_path / "put_the_bowl_on_the_plate_demo.hdf5", lengths=(3,))
    assert data_cli.main(["hdf5", "--file", str(src), "--out", str(tmp_path / "s"), "--no-progress"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["imported"] == 1
    with pytest.raises(ImportUsageError, match="missing.hdf5 does not exist"):  # the gazereg CLI reports it
        data_cli.main(["hdf5", "--file", str(tmp_path / "missing.hdf5"), "--out", str(tmp_path / "s")])
    missing = ["import", "hdf5", "--file", str(tmp_path / "missing.hdf5"), "--out", str(tmp_path / "s")]
    assert gazereg_main(missing) == 2  # a usage mistake: one line, no traceback
    err = capsys.readouterr().err
    assert (
        err.startswith("gazereg import: error: HDF5 file ")
        and err.count("\n") == 1
        and "Traceback" not in err
    )
    trunc = tmp_path / "trunc_demo.hdf5"
    trunc.write_bytes(src.read_bytes()[:2000])
    assert (
        gazereg_main(["import", "hdf5", "--file", str(trunc), "--out", str(tmp_path / "u")]) == 1
    )  # a failure
    err = capsys.readouterr().err
    assert "trunc_demo.hdf5 could not be opened" in err and err.count("\n") == 1


def test_export_priors_of_hdf5_episodes_stays_upright(tmp_path):
    pytest.importorskip("pyarrow")
    from gazereg.aggregation import AggregationConfig
    from gazereg.data.formats.lerobot_v3.export import export_priors_lerobot, read_priors_lerobot
    from gazereg.gaze.priors import PriorsConfig, make_priors

    src = write_libero(tmp_path / "put_the_bowl_on_the_plate_demo.hdf5", lengths=(4, 5), gaze=True)
    import_hdf5(cfg(src, tmp_path / "s", gaze_key="gaze_uv"))
    pc = PriorsConfig(
        store=tmp_path / "s",
        source="recorded",
        camera="agentview_rgb",
        size=(12, 16),
        aggregation=AggregationConfig(past=0, future=0),
    )
    make_priors(pc, progress=False)
    sc = read_priors_lerobot(export_priors_lerobot(tmp_path / "s", "recorded", tmp_path / "x"))
    assert sc.episode_index.tolist() == [0] * 4 + [1] * 5 and sc.index.tolist() == list(range(9))
    assert not any(e["rotation_undone"] for e in sc.info["episodes"])
    heat, ok = sc.get(1, 0)
    r, c = np.unravel_index(heat.argmax(), heat.shape)  # the peak is on the marker of the upright frame
    assert ok and (r, c) == ((HW[0] - 1 - MARK[0]) * 12 // HW[0], (HW[1] - 1 - MARK[1]) * 16 // HW[1])
    assert not sc.get(1, 1)[1]  # the NaN gaze frame is invalid


def test_non_finite_extras_are_refused_with_their_row(tmp_path):
    src = write_libero(tmp_path / "put_the_bowl_on_the_plate_demo.hdf5", lengths=(3, 4))
    with h5py.File(src, "a") as f:
        states = f["data/demo_1/states"][()]
        states[2, 7] = np.nan
        f["data/demo_1/states"][...] = states
    with pytest.raises(
        DataImportError,
        match=r"_demo\.hdf5, demo_1: dataset 'states' has 1 NaN/inf value\(s\), the first at row 2, column 7 "
        r"\(nan\) \(corrupt data\?\); pass --nonfinite-ok states",
    ):
        import_hdf5(cfg(src, tmp_path / "s"))
    _assert_no_partial(tmp_path / "s", [0])
    import_hdf5(cfg(src, tmp_path / "s", nonfinite_ok=("states",)))  # kept as it is when asked
    assert np.isnan(EpisodeStore(tmp_path / "s").read(1).extras["sim_state"][2, 7])
    with h5py.File(src, "a") as f:
        f["data/demo_0/obs/joint_states"][1, 0] = np.inf
    with pytest.raises(
        DataImportError, match=r"demo_0: dataset 'obs/joint_states' has 1 NaN/inf .* row 1, column 0"
    ):
        import_hdf5(cfg(src, tmp_path / "t"))


def test_an_import_sweeps_what_a_killed_import_left(tmp_path):
    import subprocess
    import sys

    src = write_libero(tmp_path / "put_the_bowl_on_the_plate_demo.hdf5", lengths=(3,))
    store = EpisodeStore(tmp_path / "s", create=True)
    code = (
        "import os, sys\n"
        "from gazereg.runtime.io import atomic_dir\n"
        "d = atomic_dir(sys.argv[1] + '/ep_000000'); (d.__enter__() / 'frames.agentview_rgb.npy').write_bytes(b'x')\n"
        "os._exit(0)\n"
    )
    subprocess.run([sys.executable, "-c", code, str(store.root / "episodes")], check=True)
    assert [p.name.endswith(".tmp") for p in (store.root / "episodes").iterdir()] == [True]
    import_hdf5(cfg(src, store.root))
    assert sorted(p.name for p in (store.root / "episodes").iterdir()) == ["ep_000000"]
