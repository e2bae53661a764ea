"""Import throughput (frames/s written to the episode store) for LeRobot v3 and HDF5 sources.

    python benchmarks/bench_import.py [--repeat 7] [--fixture PATH] [--demos 20 --frames 150 --size 128]

Measures, each as the median of `repeat` runs into a fresh store (fresh temporary folder):
  1. lerobot_fixture: the tiny LeRobot v3 fixture (lerobot 0.6.1: 66 frames of a 64x64 AV1 video camera plus a
     64x64 PNG camera); also the decode-only rate (read_episode without writing);
  2. lerobot_h264: a generated LeRobot v3 data set, `demos` episodes x `frames` frames, one H.264 camera of
     size x size, all episodes in one MP4 (a more realistic video workload than the fixture);
  3. hdf5_libero: a generated LIBERO-layout HDF5 file, `demos` x `frames` frames, two size x size cameras
     (turned by 180 degrees at import), proprioception and simulator state.
Prints one JSON object. Numbers depend on the machine (and on other load on it); compare ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import tempfile
from pathlib import Path

import numpy as np
from _timing import machine_info, run_times

from gazereg.data.formats.hdf5 import Hdf5ImportConfig, import_hdf5
from gazereg.data.formats.lerobot_v3 import LeRobotImportConfig, LeRobotV3Dataset, import_lerobot

DEFAULT_FIXTURE = Path(__file__).resolve().parents[2] / "shared" / "fixtures" / "lerobot_v3_tiny"


def median_rate(run, frames: int, repeat: int, warmup: int = 1) -> dict[str, float]:
    times = run_times(run, repeat, warmup)
    med = statistics.median(times)
    return {
        "frames": frames,
        "median_s": med,
        "frames_per_s": frames / med,
        "min_s": min(times),
        "max_s": max(times),
        "repeat": repeat,
    }


def import_into_fresh_store(fn, cfg_factory):
    def run():
        d = Path(tempfile.mkdtemp(prefix="bench_import_"))
        try:
            report = fn(cfg_factory(d / "store"))
            assert report["imported"] > 0
        finally:
            shutil.rmtree(d, ignore_errors=True)

    return run


def encode_h264_episodes(
    video: Path, demos: int, frames: int, size: int, fps: int
) -> tuple[dict[str, list], list[list[float]]]:
    """Encode `demos` x `frames` frames (a random image rolled one column per frame) into one H.264 MP4;
    returns the data table's index columns and a 4-d state per frame."""
    import av

    c = av.open(str(video), "w")
    s = c.add_stream("libx264", rate=fps)
    s.width = s.height = size
    s.pix_fmt = "yuv420p"
    s.options = {"g": "10", "preset": "veryfast"}
    base = np.random.default_rng(0).integers(0, 255, (size, size, 3), dtype=np.uint8)
    cols: dict[str, list] = {
        k: [] for k in ("episode_index", "frame_index", "index", "task_index", "timestamp")
    }
    state = []
    for g in range(demos * frames):
        e, i = divmod(g, frames)
        fr = av.VideoFrame.from_ndarray(np.roll(base, shift=i, axis=1), format="rgb24")
        fr.pts = g
        for pkt in s.encode(fr):
            c.mux(pkt)
        for k, v in (
            ("episode_index", e),
            ("frame_index", i),
            ("index", g),
            ("task_index", 0),
            ("timestamp", i / fps),
        ):
            cols[k].append(v)
        state.append([float(e), float(i), 0.0, 1.0])
    for pkt in s.encode():
        c.mux(pkt)
    c.close()
    return cols, state


def write_lerobot_h264(root: Path, demos: int, frames: int, size: int, fps: int = 10) -> int:
    """A LeRobot v3 data set at `root`: one H.264 camera (all episodes in one MP4), state, action and a
    `gaze.point` column; returns its number of frames."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    key = "observation.images.top"
    for sub in ("meta/episodes/chunk-000", "data/chunk-000", f"videos/{key}/chunk-000"):
        (root / sub).mkdir(parents=True)
    cols, state = encode_h264_episodes(
        root / f"videos/{key}/chunk-000/file-000.mp4", demos, frames, size, fps
    )
    g = demos * frames
    ep_rows = [{
        "episode_index": e, "tasks": ["move"], "length": frames, "data/chunk_index": 0, "data/file_index": 0,
        "dataset_from_index": e * frames, "dataset_to_index": (e + 1) * frames,
        f"videos/{key}/chunk_index": 0, f"videos/{key}/file_index": 0,
        f"videos/{key}/from_timestamp": e * frames / fps, f"videos/{key}/to_timestamp": (e + 1) * frames / fps,
    } for e in range(demos)]  # fmt: skip
    vec = pa.list_(pa.float32(), 4)
    table = {k: pa.array(v, pa.float32() if k == "timestamp" else pa.int64()) for k, v in cols.items()}
    table.update(
        {
            "observation.state": pa.array(state, vec),
            "action": pa.array(state, vec),
            "gaze.point": pa.array([[0.5, 0.5]] * g, pa.list_(pa.float32(), 2)),
        }
    )
    pq.write_table(pa.table(table), root / "data/chunk-000/file-000.parquet")
    pq.write_table(pa.Table.from_pylist(ep_rows), root / "meta/episodes/chunk-000/file-000.parquet")
    pq.write_table(pa.table({"task_index": [0], "task": ["move"]}), root / "meta/tasks.parquet")
    feats = {
        key: {"dtype": "video", "shape": [size, size, 3], "names": ["height", "width", "channels"]},
        "observation.state": {"dtype": "float32", "shape": [4]},
        "action": {"dtype": "float32", "shape": [4]},
        "gaze.point": {"dtype": "float32", "shape": [2]},
    }
    info = {
        "codebase_version": "v3.0", "fps": fps, "features": feats,
        "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
        "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
    }  # fmt: skip
    (root / "meta/info.json").write_text(json.dumps(info))
    return g


def write_libero_hdf5(path: Path, demos: int, frames: int, size: int) -> int:
    import h5py

    rng = np.random.default_rng(0)
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        data.attrs["problem_info"] = json.dumps({"language_instruction": "put the bowl on the plate"})
        for d in range(demos):
            g = data.create_group(f"demo_{d}")
            g["actions"] = rng.standard_normal((frames, 7))
            g["states"] = rng.standard_normal((frames, 79))
            obs = g.create_group("obs")
            for cam in ("agentview_rgb", "eye_in_hand_rgb"):
                obs[cam] = rng.integers(0, 255, (frames, size, size, 3), dtype=np.uint8)
            for k, dim in (("ee_pos", 3), ("ee_ori", 3), ("gripper_states", 2), ("joint_states", 7)):
                obs[k] = rng.standard_normal((frames, dim))
    return demos * frames


def fixture_rates(fx: Path, repeat: int) -> dict:
    """Import and decode-only rates of the LeRobot v3 fixture at `fx` (skipped when absent)."""
    if not (fx / "meta" / "info.json").exists():
        return {"skipped": f"no fixture at {fx}"}
    n = LeRobotV3Dataset(fx).info.get("total_frames", 66)
    r = median_rate(
        import_into_fresh_store(
            import_lerobot, lambda o: LeRobotImportConfig(root=fx, out=o, progress=False)
        ),
        n,
        repeat,
    )

    def decode_only():
        ds = LeRobotV3Dataset(fx)
        for e in ds.episodes:
            ds.read_episode(e)
        ds.close()

    r["decode_only_frames_per_s"] = median_rate(decode_only, n, repeat)["frames_per_s"]
    return r


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument(
        "--fixture", type=Path, default=Path(os.environ.get("GAZEREG_LEROBOT_FIXTURE", DEFAULT_FIXTURE))
    )
    ap.add_argument("--demos", type=int, default=20)
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--size", type=int, default=128)
    args = ap.parse_args()
    out: dict[str, object] = {
        "machine": machine_info(node=platform.node(), cpus=os.cpu_count(), python=platform.python_version()),
    }
    work = Path(tempfile.mkdtemp(prefix="bench_import_src_"))
    try:
        out["lerobot_fixture"] = fixture_rates(args.fixture, args.repeat)

        root = work / "lerobot_h264"
        n = write_lerobot_h264(root, args.demos, args.frames, args.size)
        r = median_rate(
            import_into_fresh_store(
                import_lerobot, lambda o: LeRobotImportConfig(root=root, out=o, progress=False)
            ),
            n,
            max(3, args.repeat // 2),
        )
        out["lerobot_h264"] = {**r, "episodes": args.demos, "size": args.size, "cameras": 1}

        h5 = work / "libero_bench_demo.hdf5"
        n = write_libero_hdf5(h5, args.demos, args.frames, args.size)
        r = median_rate(
            import_into_fresh_store(
                import_hdf5, lambda o: Hdf5ImportConfig(file=(h5,), out=o, progress=False)
            ),
            n,
            max(3, args.repeat // 2),
        )
        out["hdf5_libero"] = {
            **r,
            "episodes": args.demos,
            "size": args.size,
            "cameras": 2,
            "file_mb": h5.stat().st_size / 2**20,
        }
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
