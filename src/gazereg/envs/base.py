"""What evaluation and collection need from a simulator (`Env`, `Collector`) and the one registry of them.

    env_class("metaworld")               # MetaWorldEnv, imported on first use
    make_collector("libero")             # LIBERO's scripted-expert collector
    simulator("gazebo")                  # UnknownSimulator: names the registered ones
    register_simulator(Simulator("mysim", env="my.module:MyEnv", collector="my.module:MyCollector"))
    simulator_names()                    # ['libero', 'metaworld', ...and every installed plugin]

The registry maps a simulator's name to "module:Class" paths of its environment class and of its
scripted-expert collector; nothing is imported until asked for (MuJoCo, Meta-World and LIBERO are heavy, and
LIBERO lives in its own venv). Meta-World (`gazereg.envs.metaworld`) and LIBERO (`gazereg.envs.libero`) are
registered here. Another simulator comes in one of two ways:

- as a plugin (the way to ship one): an installed package declares a `Simulator` in the entry-point group
  `gazereg.simulators` (`mysim = "my_package.sim:SIMULATOR"`, see `gazereg.runtime.plugins`); a name nobody
  registered is looked up there, so `gazereg collect --env mysim`, `gazereg eval --env mysim` and
  `gazereg experiment --env mysim` know it in every process;
- registered in code (`register_simulator`), in the process that then runs (collection and evaluation with
  one worker run there; their worker processes see only plugins).

Configs hold a simulator's name as a plain `str` (`SimulatorName`), checked against this registry when the
config is built (`check_simulator`: one line listing the registered names).
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from gazereg.data.store import Episode
from gazereg.envs.camera import CameraGeometry
from gazereg.envs.perturbations import Perturbation
from gazereg.runtime import plugins
from gazereg.runtime.errors import UsageError

SimulatorName = str
"""a registered simulator's name (`simulator_names()`); checked when a config holding one is built"""


class UnknownSimulator(UsageError):
    """A simulator name that is not registered (a user mistake: `gazereg` exits 2 naming the registered ones)."""


class Env(Protocol):
    """A simulated task with RGB cameras, proprioception and an instruction (gymnasium's reset/step API).

    Constructor: `Env(task, cameras=, image_size=, max_steps=, perturbation=, gl_backend=)`.

    Observations: {"images": {camera: uint8 (H, W, 3) upright, as the policy sees it}, "state": float32 (S,),
    "instruction": str}. `reset(seed=s)` starts setup seed `s` (the simulator fixes the scene from it; the same
    seed gives the same setup in any process). `info` after reset and every step: success (bool), setup_seed,
    steps, contact and grasp (bool), world positions `<name>_pos` (3,) in metres (obj, goal, hand, maybe obj2)
    and, where the simulator measures it, `obj_to_target`: the object's (or hand's) distance to its target
    in metres."""

    task: str
    cameras: tuple[str, ...]
    image_size: tuple[int, int]
    max_steps: int
    fps: float
    instruction: str

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]: ...

    def step(self, action: np.ndarray) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]: ...

    def render_images(self) -> dict[str, np.ndarray]: ...

    def camera_geometry(self, camera: str) -> CameraGeometry: ...

    def project(self, points: np.ndarray, camera: str) -> np.ndarray:
        """World points (..., 3) -> normalised (u right, v down) (..., 2) in `camera`'s image as returned."""
        ...

    def key_points(self) -> dict[str, np.ndarray]: ...

    def contact_state(self) -> tuple[bool, bool]: ...

    @property
    def perturbation(self) -> Perturbation: ...

    def set_perturbation(self, perturbation: Perturbation | None) -> None: ...

    def close(self) -> None: ...


class Collector(Protocol):
    """A simulator's scripted expert for `gazereg collect`: tasks, its environments and one rollout."""

    name: str
    default_cameras: tuple[str, ...]
    default_max_steps: int
    max_steps_limit: int

    def tasks(self, requested: Sequence[str]) -> tuple[str, ...]:
        """Canonical task names (suites expanded); ValueError or KeyError naming the unknown ones."""
        ...

    def episode_task(self, task: str) -> str:
        """The `task` an episode of `task` is stored under."""
        ...

    def make_env(self, task: str, cfg: Any) -> Env:
        """The environment of `task` with the render settings of `cfg` (a resolved CollectConfig)."""
        ...

    def rollout(
        self, env: Env, seed: int, action_noise: float, max_steps: int
    ) -> tuple[Episode, dict[str, Any]]:
        """The expert on setup `seed`: the episode (also when it failed) and its summary (task, seed, success,
        steps, seconds, cpu_seconds)."""
        ...


@dataclass(frozen=True)
class Simulator:
    """Where a simulator's pieces live: "module:Class" paths, imported on first use; and how many of its
    environments an evaluation worker steps in lockstep by default (`EvalConfig.batch`)."""

    name: str
    env: str
    collector: str
    lockstep: int = 1


_SIMULATORS: dict[str, Simulator] = {
    "metaworld": Simulator(
        "metaworld",
        env="gazereg.envs.metaworld.env:MetaWorldEnv",
        collector="gazereg.envs.metaworld.collector:MetaWorldCollector",
        lockstep=8,  # small environments; the policy is half of a step (benchmarks/bench_eval.py)
    ),
    "libero": Simulator(
        "libero",
        env="gazereg.envs.libero.env:LiberoEnv",
        collector="gazereg.envs.libero.collector:LiberoCollector",
        lockstep=1,  # an environment holds ~1.2 GB (gazereg.envs.cache) and rendering dominates its step
    ),
}


def register_simulator(sim: Simulator) -> Simulator:
    """Register (or replace) a simulator under `sim.name`; returns it."""
    if not isinstance(sim, Simulator):
        raise TypeError(f"{sim!r} is not a gazereg.envs.base.Simulator")
    _SIMULATORS[sim.name] = sim
    return sim


def unregister_simulator(name: str) -> None:
    _SIMULATORS.pop(name, None)


def simulator_names() -> list[str]:
    """The registered simulators and those installed plugins provide, sorted."""
    return sorted({*_SIMULATORS, *plugins.plugin_names(plugins.SIMULATORS)})


def simulator(name: str) -> Simulator:
    """The registered simulator `name`, else the installed plugin of that name (registered on first use);
    UnknownSimulator names the registered ones."""
    if name not in _SIMULATORS and (found := plugins.load_plugin(plugins.SIMULATORS, name, "simulator")):
        value = plugins.plugin_value(plugins.SIMULATORS, name)
        if not isinstance(found, Simulator) or found.name != name:
            raise TypeError(
                f"{plugins.where(plugins.SIMULATORS, name, value, 'simulator')} names {found!r}; it must name "
                f"a gazereg.envs.base.Simulator called {name!r}"
            )
        register_simulator(found)
    if name not in _SIMULATORS:
        raise UnknownSimulator(f"unknown simulator {name!r}; choose one of {simulator_names()}")
    return _SIMULATORS[name]


def check_simulator(name: object, flag: str, error: type[UsageError] = UsageError) -> None:
    """Refuse, when a config is built, a simulator nobody registered: `error` naming `flag` and listing the
    registered names, one line."""
    if not isinstance(name, str):
        raise error(f"{flag} must be a simulator name, got {name!r}")
    try:
        simulator(name)
    except UnknownSimulator as e:
        raise error(f"{flag}: {e}") from None


def _load(path: str) -> Any:
    module, attr = path.split(":")
    return getattr(importlib.import_module(module), attr)


def env_class(name: str) -> type[Env]:
    """The environment class of simulator `name` (imports its module)."""
    return _load(simulator(name).env)


def make_collector(name: str) -> Collector:
    """A collector of simulator `name` (imports its module)."""
    return _load(simulator(name).collector)()


def image_hw(image_size: int | Sequence[int]) -> tuple[int, int]:
    """An image size (side, or (height, width)) as positive (height, width) pixels; ValueError otherwise."""
    H, W = (image_size, image_size) if isinstance(image_size, int) else tuple(image_size)
    if H <= 0 or W <= 0:
        raise ValueError(f"image size must be positive, got {image_size}")
    return int(H), int(W)


def check_cameras(cameras: Sequence[str]) -> tuple[str, ...]:
    """Camera names as a tuple; ValueError for duplicates."""
    cams = tuple(cameras)
    if len(set(cams)) != len(cams):
        raise ValueError(f"duplicate cameras in {cams}")
    return cams


def check_render_mode(render_mode: str | None) -> None:
    if render_mode not in (None, "rgb_array"):
        raise ValueError(f"render_mode must be 'rgb_array' or None, got {render_mode!r}")
