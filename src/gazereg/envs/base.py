"""The one registry of simulators: where each one's `Env` and `Collector` (`gazereg.envs.interface`) live.

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
from dataclasses import dataclass
from typing import Any

from gazereg.envs.interface import Collector, Env
from gazereg.runtime import plugins
from gazereg.runtime.errors import UsageError

SimulatorName = str
"""a registered simulator's name (`simulator_names()`); checked when a config holding one is built"""


class UnknownSimulator(UsageError):
    """A simulator name that is not registered (a user mistake: `gazereg` exits 2 naming the registered ones)."""


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
    # Gym-Aloha (transfer cube, insertion): runs in the Aloha lane's venv (scripts/aloha_lane.sh).
    "aloha": Simulator(
        "aloha",
        env="gazereg.envs.aloha.env:AlohaEnv",
        collector="gazereg.envs.aloha.collector:AlohaCollector",
        lockstep=1,
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
