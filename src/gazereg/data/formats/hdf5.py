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
    rewards / dones as extras["reward"] / extras["done"];
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
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gazereg.data.importers import (
    DataImportError,
    SourceEpisode,
    recorded_gaze,
    rotated_cameras,
    write_episodes,
)
from gazereg.data.store import Episode, EpisodeStore

log = logging.getLogger(__name__)

_DEMO_RE = re.compile(r"^demo_(\d+)$")
_STATE_PRESETS = (
    ("ee_pos", "ee_ori", "gripper_states"),  # LIBERO
    ("robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos"),  # robomimic
)


def _h5py() -> Any:
    try:
        import h5py
    except ImportError as e:  # pragma: no cover - the `data` extra declares it
        raise ImportError("HDF5 import needs h5py: pip install 'gazereg[data]' (or pip install h5py)") from e
    return h5py


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
    progress: bool = True


def _attr_str(v: Any) -> str:
    if isinstance(v, bytes):
        return v.decode("utf-8", "replace")
    if isinstance(v, np.ndarray) and v.shape == ():
        return _attr_str(v.item())
    return str(v)


def _json_attr(attrs: Any, key: str) -> dict[str, Any]:
    if key not in attrs:
        return {}
    try:
        out = json.loads(_attr_str(attrs[key]))
    except (json.JSONDecodeError, TypeError):
        return {}
    return out if isinstance(out, dict) else {}


def instruction_from_filename(path: str | Path) -> str:
    """`KITCHEN_SCENE3_turn_on_the_stove_demo.hdf5` -> "turn on the stove"."""
    stem = Path(path).stem
    stem = re.sub(r"_demo$", "", stem)
    stem = re.sub(r"^[A-Z0-9_]*SCENE\d+_", "", stem)
    return stem.replace("_", " ").strip()


class Hdf5Demos:
    """One open HDF5 file of demonstrations. Use as a context manager or call close()."""

    def __init__(self, path: str | Path):
        h5py = _h5py()
        self.path = Path(path)
        if not self.path.exists():
            raise DataImportError(f"HDF5 file {self.path} does not exist")
        try:
            self.f = h5py.File(self.path, "r")
        except OSError as e:
            raise DataImportError(
                f"HDF5 file {self.path} could not be opened (corrupt or truncated?): {e}"
            ) from e
        if "data" not in self.f:
            self.close()
            raise DataImportError(f"HDF5 file {self.path} has no 'data' group (expected data/demo_<n>/...)")
        self.data = self.f["data"]
        demos = {}
        for k in self.data:
            m = _DEMO_RE.match(k)
            if m:
                demos[int(m.group(1))] = k
        if not demos:
            have = list(self.data)[:10]
            self.close()
            raise DataImportError(f"HDF5 file {self.path} has no data/demo_<n> groups (has {have})")
        self.demos: dict[int, str] = dict(sorted(demos.items()))
        attrs = self.data.attrs
        self.problem_info = _json_attr(attrs, "problem_info")
        self.env_args = _json_attr(attrs, "env_args")
        self.is_libero = (
            bool(self.problem_info)
            or "bddl_file_name" in attrs
            or "libero" in json.dumps(self.env_args).lower()
            or "libero" in str(self.path).lower()
        )

    def __enter__(self) -> Hdf5Demos:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        f = getattr(self, "f", None)
        if f is not None:
            f.close()
            self.f = None

    def fingerprint(self) -> str:
        blob = json.dumps(
            {"name": self.path.name, "demos": list(self.demos), "problem_info": self.problem_info},
            sort_keys=True,
        )
        return hashlib.sha256(blob.encode()).hexdigest()[:16]

    def length(self, n: int) -> int:
        where = f"{self.path}, {self.demos[n]}"
        g = self.data[self.demos[n]]
        if "actions" not in g:
            raise DataImportError(f"{where}: no 'actions' dataset")
        return int(g["actions"].shape[0])

    def camera_keys(self, n: int) -> list[str]:
        g = self.data[self.demos[n]]
        if "obs" not in g:
            return []
        return [k for k, d in g["obs"].items() if d.dtype == np.uint8 and d.ndim == 4 and d.shape[-1] == 3]

    def instruction(self, n: int | None = None) -> str:
        lang = self.problem_info.get("language_instruction")
        if isinstance(lang, list) and lang:
            lang = lang[0]
        if lang:
            return str(lang).strip()
        for attrs in ([self.data[self.demos[n]].attrs] if n is not None else []) + [self.data.attrs]:
            if "language_instruction" in attrs:
                return _attr_str(attrs["language_instruction"]).strip()
        return instruction_from_filename(self.path)

    def read(
        self,
        n: int,
        cameras: list[str],
        state_keys: tuple[str, ...],
        rotate: list[str],
        instruction: str,
        task: str,
        gaze_key: str | None,
        gaze_camera: str | None,
    ) -> Episode:
        key = self.demos[n]
        where = f"{self.path}, {key}"
        try:
            g = self.data[key]
            obs = g.get("obs", {})
            T = self.length(n)
            if T == 0:
                raise DataImportError(f"{where}: the demo is empty (0 actions)")

            def get(k: str, allow_top: bool = True) -> np.ndarray:
                if k in obs:
                    arr = obs[k][()]
                elif allow_top and k in g:
                    arr = g[k][()]
                else:
                    raise DataImportError(f"{where}: no dataset {k!r} (obs keys: {sorted(obs)})")
                if arr.shape[:1] != (T,):
                    raise DataImportError(
                        f"{where}: {k!r} has {arr.shape[0] if arr.ndim else 0} rows but the demo has {T} actions"
                    )
                return arr

            num = g.attrs.get("num_samples")
            if num is not None and int(num) != T:
                raise DataImportError(
                    f"{where}: num_samples attribute is {int(num)} but actions has {T} rows"
                )
            action = get("actions").astype(np.float32).reshape(T, -1)
            frames = {}
            for cam in cameras:
                if cam not in obs:
                    raise DataImportError(f"{where}: camera {cam!r} is missing (obs keys: {sorted(obs)})")
                fr = get(cam)
                if fr.dtype != np.uint8 or fr.ndim != 4 or fr.shape[-1] != 3:
                    raise DataImportError(
                        f"{where}: camera {cam!r} must be uint8 (T, H, W, 3), got {fr.dtype} {fr.shape}"
                    )
                frames[cam] = np.ascontiguousarray(fr[:, ::-1, ::-1]) if cam in rotate else fr
            state = (
                np.concatenate([get(k).astype(np.float32).reshape(T, -1) for k in state_keys], axis=1)
                if state_keys
                else np.zeros((T, 0), np.float32)
            )
            extras: dict[str, np.ndarray] = {}
            for k, d in obs.items():
                if k in cameras or k in state_keys or k == gaze_key or d.ndim == 0 or d.shape[0] != T:
                    continue
                if d.dtype.kind in "biuf" and d.ndim <= 3:
                    extras[f"obs.{k}"] = d[()]
            for src, dst in (("states", "sim_state"), ("rewards", "reward"), ("dones", "done")):
                if src in g and src not in state_keys and g[src].shape[:1] == (T,):
                    extras[dst] = g[src][()]
            meta: dict[str, Any] = {"demo": key, "file": self.path.name}
            if gaze_key:
                cam = gaze_camera or (cameras[0] if cameras else None)
                if cam not in cameras:
                    raise DataImportError(
                        f"{where}: gaze camera {cam!r} is not among the imported cameras {cameras}"
                    )
                uv, valid = recorded_gaze(
                    get(gaze_key, allow_top=False), f"{where}: gaze {gaze_key!r}", cam in rotate
                )
                extras[f"gaze_uv.{cam}"], extras[f"gaze_valid.{cam}"] = uv, valid
                meta["gaze"] = {"camera": cam, "key": gaze_key}
        except DataImportError:
            raise
        except (OSError, KeyError, ValueError, RuntimeError) as e:  # h5py read errors on corrupt chunks
            raise DataImportError(f"{where}: could not be read (corrupt file?): {e}") from e
        if rotate:
            meta["orientation_applied"] = dict.fromkeys(rotate, "rot180")
        if self.env_args.get("env_name"):
            meta["env_name"] = self.env_args["env_name"]
        if self.problem_info:
            meta["problem_info"] = self.problem_info
        return Episode(
            task=task,
            instruction=instruction,
            frames=frames,
            state=state,
            action=action,
            extras=extras,
            meta=meta,
        )


def default_state_keys(demos: Hdf5Demos, n: int) -> tuple[str, ...]:
    g = demos.data[demos.demos[n]]
    obs = g.get("obs", {})
    for keys in _STATE_PRESETS:
        if all(k in obs for k in keys):
            return keys
    return ("states",) if "states" in g else ()


def import_hdf5(cfg: Hdf5ImportConfig) -> dict[str, Any]:
    """Import (or resume importing) HDF5 demonstrations into cfg.out; returns counts and throughput."""
    if not cfg.file:
        raise DataImportError("no HDF5 file given (--file PATH [PATH ...])")
    opened: list[Hdf5Demos] = []
    try:
        items: list[SourceEpisode] = []
        offset = cfg.index_offset
        for path in cfg.file:
            demos = Hdf5Demos(path)
            opened.append(demos)
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
                raise DataImportError("--gaze-camera needs --gaze-key (the obs key holding the gaze points)")
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
            for n in demos.demos:
                instruction = cfg.instruction or demos.instruction(n)
                identity = {
                    "format": "hdf5",
                    "path": str(demos.path.resolve()),
                    "file": demos.path.name,
                    "dataset": demos.fingerprint(),
                    "demo": demos.demos[n],
                    "episode": demos.demos[n],
                    "settings": settings,
                }

                def load(
                    d: Hdf5Demos = demos,
                    n: int = n,
                    instruction: str = instruction,
                    task: str = task,
                    cams: list[str] = cams,
                    sk: tuple[str, ...] = state_keys,
                    rot: list[str] = rotate,
                ) -> Episode:
                    return d.read(n, cams, sk, rot, instruction, task, cfg.gaze_key, cfg.gaze_camera)

                items.append(SourceEpisode(index=offset + n, identity=identity, load=load))
            offset += max(demos.demos) + 1
        store = EpisodeStore(cfg.out, create=True)
        return write_episodes(store, items, total=len(items), desc="import hdf5", progress=cfg.progress)
    finally:
        for d in opened:
            d.close()


def import_main(argv: list[str]) -> int:
    from gazereg.runtime.config import parse

    cfg = parse(
        {"default": Hdf5ImportConfig},
        argv,
        prog="gazereg import hdf5",
        description=(__doc__ or "").split("\n\n")[0],
    )
    report = import_hdf5(cfg)
    print(json.dumps({"store": str(cfg.out), **report}))
    return 0
