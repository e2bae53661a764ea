"""Reading LIBERO / robomimic HDF5 demonstration files (h5py, imported when a file is opened).

`Hdf5Demos` is one open file (data/demo_<n>/...; the layout is in gazereg.data.formats.hdf5), `Demo` one demo
group being read, each dataset checked against the demo's number of actions. Every problem is raised as a
`DataImportError` naming the file and the demo.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gazereg.data.errors import DataImportError, ImportUsageError
from gazereg.data.imports import check_finite, recorded_gaze
from gazereg.data.store import Episode

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
    """One open HDF5 file of demonstrations. Use as a context manager or call close().

    nonfinite_ok: datasets (obs keys, or states / rewards / dones) whose NaN/inf values are imported as they
    are; NaN/inf anywhere else is refused with the dataset, the demo and the first bad row."""

    def __init__(self, path: str | Path, nonfinite_ok: tuple[str, ...] = ()):
        h5py = _h5py()
        self.path = Path(path)
        self.nonfinite_ok = tuple(nonfinite_ok)
        if not self.path.exists():
            raise ImportUsageError(f"HDF5 file {self.path} does not exist")
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

    def demo(self, n: int) -> Demo:
        """demo_<n>, checked: it has actions, at least one, and as many as its num_samples attribute says."""
        key = self.demos[n]
        g = self.data[key]
        demo = Demo(g, g.get("obs", {}), self.length(n), f"{self.path}, {key}", self.nonfinite_ok)
        if demo.T == 0:
            raise DataImportError(f"{demo.where}: the demo is empty (0 actions)")
        num = g.attrs.get("num_samples")
        if num is not None and int(num) != demo.T:
            raise DataImportError(
                f"{demo.where}: num_samples attribute is {int(num)} but actions has {demo.T} rows"
            )
        return demo

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
        """demo_<n> as an episode (what goes where: the module docstring); cameras in `rotate` are turned by
        180 degrees, with the gaze when `gaze_key` names a gaze dataset of one of them."""
        where = f"{self.path}, {self.demos[n]}"
        try:
            demo = self.demo(n)
            action = demo.get("actions").astype(np.float32).reshape(demo.T, -1)
            frames = demo.cameras(cameras, rotate)
            state = demo.state(state_keys)
            extras = demo.extras(cameras, state_keys, gaze_key)
            meta: dict[str, Any] = {"demo": self.demos[n], "file": self.path.name}
            if gaze_key:
                cam = gaze_camera or (cameras[0] if cameras else None)
                extras.update(demo.gaze(gaze_key, cam, cameras, rotate))
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


@dataclass(frozen=True)
class Demo:
    """One demo group being read, every dataset checked against its length."""

    g: Any
    """the h5py group data/demo_<n>"""
    obs: Any
    """its obs group (an empty dict when it has none)"""
    T: int
    """its number of actions"""
    where: str
    """file and demo, for error messages"""
    nonfinite_ok: tuple[str, ...] = ()
    """datasets whose NaN/inf values are kept (others are refused)"""

    def get(self, k: str, allow_top: bool = True) -> np.ndarray:
        """obs/<k> (else <k> at the demo's top level when `allow_top`), which must have T rows."""
        if k in self.obs:
            arr = self.obs[k][()]
        elif allow_top and k in self.g:
            arr = self.g[k][()]
        else:
            raise DataImportError(f"{self.where}: no dataset {k!r} (obs keys: {sorted(self.obs)})")
        if arr.shape[:1] != (self.T,):
            raise DataImportError(
                f"{self.where}: {k!r} has {arr.shape[0] if arr.ndim else 0} rows but the demo has {self.T} actions"
            )
        return arr

    def cameras(self, cameras: list[str], rotate: list[str]) -> dict[str, np.ndarray]:
        """uint8 (T, H, W, 3) frames per camera, those in `rotate` turned by 180 degrees."""
        frames = {}
        for cam in cameras:
            if cam not in self.obs:
                raise DataImportError(
                    f"{self.where}: camera {cam!r} is missing (obs keys: {sorted(self.obs)})"
                )
            fr = self.get(cam)
            if fr.dtype != np.uint8 or fr.ndim != 4 or fr.shape[-1] != 3:
                raise DataImportError(
                    f"{self.where}: camera {cam!r} must be uint8 (T, H, W, 3), got {fr.dtype} {fr.shape}"
                )
            frames[cam] = np.ascontiguousarray(fr[:, ::-1, ::-1]) if cam in rotate else fr
        return frames

    def state(self, state_keys: tuple[str, ...]) -> np.ndarray:
        """float32 (T, S): the `state_keys` datasets concatenated ((T, 0) without any)."""
        if not state_keys:
            return np.zeros((self.T, 0), np.float32)
        return np.concatenate(
            [self.get(k).astype(np.float32).reshape(self.T, -1) for k in state_keys], axis=1
        )

    def extras(
        self, cameras: list[str], state_keys: tuple[str, ...], gaze_key: str | None
    ) -> dict[str, np.ndarray]:
        """Every per-frame numeric obs dataset that is not a camera, state or gaze as `obs.<key>`, and the
        demo's states / rewards / dones (unless in the state) as sim_state / reward / done; NaN/inf values are
        refused (DataImportError naming the dataset and the row) unless the dataset is in `nonfinite_ok`."""
        extras: dict[str, np.ndarray] = {}
        for k, d in self.obs.items():
            if k in cameras or k in state_keys or k == gaze_key or d.ndim == 0 or d.shape[0] != self.T:
                continue
            if d.dtype.kind in "biuf" and d.ndim <= 3:
                extras[f"obs.{k}"] = self._finite(d[()], f"obs/{k}", k)
        for src, dst in (("states", "sim_state"), ("rewards", "reward"), ("dones", "done")):
            if src in self.g and src not in state_keys and self.g[src].shape[:1] == (self.T,):
                extras[dst] = self._finite(self.g[src][()], src, src)
        return extras

    def _finite(self, arr: np.ndarray, path: str, name: str) -> np.ndarray:
        return check_finite(arr, f"{self.where}: dataset {path!r}", name, self.nonfinite_ok)

    def gaze(
        self, gaze_key: str, cam: str | None, cameras: list[str], rotate: list[str]
    ) -> dict[str, np.ndarray]:
        """The recorded gaze of camera `cam` as extras gaze_uv.<cam> and gaze_valid.<cam>."""
        if cam not in cameras:
            raise ImportUsageError(
                f"{self.where}: gaze camera {cam!r} is not among the imported cameras {cameras}"
            )
        uv, valid = recorded_gaze(
            self.get(gaze_key, allow_top=False), f"{self.where}: gaze {gaze_key!r}", cam in rotate
        )
        return {f"gaze_uv.{cam}": uv, f"gaze_valid.{cam}": valid}


def default_state_keys(demos: Hdf5Demos, n: int) -> tuple[str, ...]:
    g = demos.data[demos.demos[n]]
    obs = g.get("obs", {})
    for keys in _STATE_PRESETS:
        if all(k in obs for k in keys):
            return keys
    return ("states",) if "states" in g else ()
