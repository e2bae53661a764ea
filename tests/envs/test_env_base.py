"""The simulator registry: names -> lazily imported environment and collector classes."""

from __future__ import annotations

import pytest

from gazereg.envs import base
from gazereg.envs.base import Simulator, UnknownSimulator, env_class, make_collector, register_simulator
from gazereg.runtime.errors import UsageError


def test_unknown_simulator_names_the_registered_ones():
    with pytest.raises(
        UnknownSimulator,
        match=r"unknown simulator 'gazebo'; choose one of \['aloha', 'libero', 'metaworld'\]",
    ):
        base.simulator("gazebo")
    with pytest.raises(UsageError):  # a user mistake: `gazereg` exits 2 with its message
        make_collector("gazebo")


def test_builtin_simulators_resolve_their_classes():
    pytest.importorskip("metaworld")
    from gazereg.envs.metaworld.collector import MetaWorldCollector
    from gazereg.envs.metaworld.env import MetaWorldEnv

    assert env_class("metaworld") is MetaWorldEnv
    assert isinstance(make_collector("metaworld"), MetaWorldCollector)
    assert make_collector("metaworld").instruction("reach-v3") == "Reach the goal with the gripper."
    # LIBERO's classes import without LIBERO installed; only building an environment needs it.
    assert make_collector("libero").default_cameras == ("agentview_rgb", "eye_in_hand_rgb")


def test_a_registered_simulator_is_found(monkeypatch):
    monkeypatch.setattr(base, "_SIMULATORS", dict(base._SIMULATORS))
    register_simulator(Simulator("fake", env="collections:OrderedDict", collector="collections:Counter"))
    assert "fake" in base.simulator_names()
    assert env_class("fake").__name__ == "OrderedDict" and make_collector("fake") == {}
