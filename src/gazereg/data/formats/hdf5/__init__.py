"""LIBERO / robomimic HDF5 demonstrations into the episode store.

    gazereg import hdf5 --file libero_spatial/pick_up_..._demo.hdf5 [more.hdf5 ...] --out data/libero

Layout read (robomimic's, which LIBERO uses):

    data/                       attrs: problem_info (LIBERO: JSON with language_instruction), env_args (JSON),
                                       bddl_file_name (LIBERO)
    data/demo_<n>/actions       (T, A)
    data/demo_<n>/states        (T, S_sim)   full simulator state (kept as extras["sim_state"])
    data/demo_<n>/obs/<key>     (T, H, W, 3) uint8 cameras (agentview_rgb, eye_in_hand_rgb, agentview_image,
                                robot0_eye_in_hand_image, ...) and (T, d) proprioception
    data/demo_<n>/rewards, dones  (T,)

What lands in the store, one episode per demo:
  - frames.<obs key> for every uint8 (T, H, W, 3) observation (or `cameras`);
  - state: `state_keys` concatenated (obs keys, or `states`); by default LIBERO's ee_pos + ee_ori +
    gripper_states (8-d), else robomimic's robot0_eef_pos + robot0_eef_quat + robot0_gripper_qpos, else
    the demo's `states`, else (T, 0);
  - action = actions; every other per-frame obs key as extras["obs.<key>"], states as extras["sim_state"],
    rewards / dones as extras["reward"] / extras["done"]; NaN/inf in any of them is refused (naming the
    dataset, the demo and the first bad row) unless `nonfinite_ok` names the dataset, and in the state and
    actions always;
  - instruction: `instruction`, else problem_info's language_instruction, else a language_instruction
    attribute, else the file name (`pick_up_the_bowl_demo.hdf5` -> "pick up the bowl"; LIBERO-90's
    `KITCHEN_SCENE3_` prefix dropped); task: `task`, else the file name without `_demo`.
  - optional recorded gaze: `gaze_key` names an obs key with (T, 2) normalised (u, v) points in the file's
    frame; it is stored as extras["gaze_uv.<gaze_camera>"] + extras["gaze_valid.<gaze_camera>"].

Orientation (decision): the store holds frames upright, as the policy sees them (the store's contract), so
rotations happen here, once. LIBERO writes its camera images upside down (robosuite's OpenGL origin; OpenVLA
and LeRobot turn both the agentview and the wrist image by 180 degrees), so `rotate180="auto"` turns every
camera of a LIBERO file (detected by problem_info / bddl_file_name / "libero" in env_args or the file name)
by 180 degrees and leaves other files (robomimic already flips its images upright) alone. `none`, `all` or a
comma-separated camera list override it. Gaze points of a turned camera become (1 - u, 1 - v). What was
applied is recorded in meta["orientation_applied"] = {"agentview_rgb": "rot180", ...}, so downstream
geometry (PatchGeometry) uses orientation "none" for these frames; a live LIBERO environment must turn its
renders the same way before they reach the policy.

Store index: demo_<n> of the first file -> index_offset + n; each further file starts after the previous
file's largest demo number, so indices are fixed by the file list and a re-run resumes.

Modules: gazereg.data.formats.hdf5.demos (`Hdf5Demos`: reading one file, demo by demo) and this one (the import).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gazereg.data.errors import DataImportError, ImportUsageError
from gazereg.data.formats.hdf5.demos import Hdf5Demos, default_state_keys
from gazereg.data.imports import SourceEpisode, import_into, rotated_cameras
from gazereg.data.store import Episode
from gazereg.runtime.config import parse


@dataclass(frozen=True)
class Hdf5ImportConfig:
    file: tuple[Path, ...] = ()
    """one or more HDF5 files (each with data/demo_<n>/...)"""
    out: Path = Path("data/demos")
    """episode store to write (created if missing; episodes already there are skipped)"""
    cameras: tuple[str, ...] = ()
    """obs keys to import as cameras; default: every uint8 (T, H, W, 3) observation"""
    state_keys: tuple[str, ...] = ()
    """obs keys (or `states`) concatenated into the state; default: see the module docstring"""
    instruction: str | None = None
    """language instruction for every demo (default: from the file's attributes, else its name)"""
    task: str | None = None
    """task name (default: the file name without _demo)"""
    rotate180: str = "auto"
    """auto (every camera of LIBERO files) | none | all | comma-separated camera names"""
    gaze_key: str | None = None
    """obs key holding (T, 2) normalised gaze points, if the file has any"""
    gaze_camera: str | None = None
    """camera the gaze refers to (default: the first camera)"""
    index_offset: int = 0
    """store index of demo_0 of the first file"""
    nonfinite_ok: tuple[str, ...] = ()
    """datasets (obs keys, or states / rewards / dones) whose NaN/inf values are imported as they are
    (by default NaN/inf is refused, naming the dataset and the first bad row)"""
    progress: bool = True


def plan_file(cfg: Hdf5ImportConfig, demos: Hdf5Demos, offset: int) -> list[SourceEpisode]:
    """The episodes of one open file (demo_<n> -> store index offset + n), each with its identity (compared on
    resume) and its loader; the settings are resolved from the file's first demo and checked first."""
    first = next(iter(demos.demos))
    cams = list(cfg.cameras) or demos.camera_keys(first)
    if not cams:
        raise DataImportError(
            f"{demos.path}, {demos.demos[first]}: no uint8 (T, H, W, 3) camera observations; name them with --cameras"
        )
    state_keys = tuple(cfg.state_keys) or default_state_keys(demos, first)
    rotate = rotated_cameras(
        cfg.rotate180, cams, auto=cams if demos.is_libero else [], where=f" from {demos.path}"
    )
    if cfg.gaze_camera is not None and cfg.gaze_key is None:
        raise ImportUsageError("--gaze-camera needs --gaze-key (the obs key holding the gaze points)")
    task = cfg.task or re.sub(r"_demo$", "", demos.path.stem)
    settings = {
        "cameras": cams,
        "state_keys": list(state_keys),
        "rotate180": rotate,
        "gaze_key": cfg.gaze_key,
        "gaze_camera": cfg.gaze_camera,
        "task": task,
        "instruction": cfg.instruction,
    }
    source = {"format": "hdf5", "path": str(demos.path.resolve()), "file": demos.path.name}
    items = []
    for n in demos.demos:
        instruction = cfg.instruction or demos.instruction(n)
        demo = demos.demos[n]
        identity = {
            **source,
            "dataset": demos.fingerprint(),
            "demo": demo,
            "episode": demo,
            "settings": settings,
        }

        def load(n: int = n, instruction: str = instruction) -> Episode:
            return demos.read(n, cams, state_keys, rotate, instruction, task, cfg.gaze_key, cfg.gaze_camera)

        items.append(SourceEpisode(index=offset + n, identity=identity, load=load))
    return items


def import_hdf5(cfg: Hdf5ImportConfig) -> dict[str, Any]:
    """Import (or resume importing) HDF5 demonstrations into cfg.out; returns counts and throughput."""
    if not cfg.file:
        raise ImportUsageError("no HDF5 file given (--file PATH [PATH ...])")
    opened: list[Hdf5Demos] = []
    try:
        items: list[SourceEpisode] = []
        offset = cfg.index_offset
        for path in cfg.file:
            demos = Hdf5Demos(path, nonfinite_ok=cfg.nonfinite_ok)
            opened.append(demos)
            items += plan_file(cfg, demos, offset)
            offset += max(demos.demos) + 1
        return import_into(cfg.out, items, total=len(items), desc="import hdf5", progress=cfg.progress)
    finally:
        for d in opened:
            d.close()


def import_main(argv: list[str]) -> int:
    cfg = parse(
        {"default": Hdf5ImportConfig},
        argv,
        prog="gazereg import hdf5",
        description=(__doc__ or "").split("\n\n")[0],
    )
    report = import_hdf5(cfg)
    print(json.dumps({"store": str(cfg.out), **report}))
    return 0
