"""The policy registry: policy type name -> `Policy` class, and the factories built on it.

    register_policy(MyPolicy)                  # under MyPolicy.config_class.type
    make_policy(config, data)                  # a fresh policy of config's registered type, resolved from data
    load_policy(folder)                        # whichever registered type the folder's config.json names
    policy_config_class("vla")                 # the config class `--policy.type vla` selects

The built-in policies are registered here; another policy registers itself (`register_policy`) before a
config naming it is parsed or a folder holding it is loaded. Registration is per process: processes that
only import gazereg (evaluation's spawned workers when `workers > 1`, `accelerate launch -m
gazereg.training.loop`) know the built-ins only, so run a policy registered elsewhere in processes that
import the module registering it (or evaluate it with `workers=1`).
"""

from __future__ import annotations

import json
import operator
from pathlib import Path
from typing import Any

from gazereg.data.dataset import StoreInfo
from gazereg.policies.base import CONFIG_FILE, Policy, PolicyConfig
from gazereg.policies.vla.modeling_vla import VLAPolicy
from gazereg.runtime.config import Choice


class PolicyRegistry:
    """Policy classes by type name (the `type` of their config class)."""

    def __init__(self, *classes: type[Policy]):
        self._classes: dict[str, type[Policy]] = {}
        for cls in classes:
            self.register(cls)

    def register(self, cls: type[Policy]) -> type[Policy]:
        """Register `cls` under its config class's `type`; registering the same class again is a no-op.
        Returns `cls` (usable as a class decorator)."""
        if not (isinstance(cls, type) and issubclass(cls, Policy)):
            raise TypeError(f"{cls!r} is not a gazereg.policies.base.Policy subclass")
        config_class = cls.config_class
        name = config_class.type
        if not (issubclass(config_class, PolicyConfig) and config_class is not PolicyConfig and name):
            raise TypeError(f"{cls.__name__}.config_class must be a PolicyConfig subclass with a `type` name")
        known = self._classes.get(name)
        if known is not None and known is not cls:
            raise ValueError(
                f"policy type {name!r} is already registered to {known.__module__}.{known.__name__}"
            )
        self._classes[name] = cls
        return cls

    def unregister(self, name: str) -> None:
        self._classes.pop(name, None)

    def names(self) -> list[str]:
        return sorted(self._classes)

    def policy_class(self, name: str) -> type[Policy]:
        if name not in self._classes:
            raise KeyError(f"unknown policy type {name!r}; registered: {self.names()}")
        return self._classes[name]

    def config_class(self, name: str) -> type[PolicyConfig]:
        return self.policy_class(name).config_class


POLICIES = PolicyRegistry(VLAPolicy)
"""The process's policy registry (the built-ins; `register_policy` adds more)."""

POLICY_CHOICE = Choice(lookup=POLICIES.config_class, name_of=operator.attrgetter("type"))
"""Metadata of a config field holding a `PolicyConfig`: `--FIELD.type NAME` picks the registered class on the
command line and the saved config records the name (gazereg.runtime.config.Choice)."""


def register_policy(cls: type[Policy]) -> type[Policy]:
    """Register a policy class under its config class's `type` (see `PolicyRegistry.register`)."""
    return POLICIES.register(cls)


def unregister_policy(name: str) -> None:
    POLICIES.unregister(name)


def available_policies() -> list[str]:
    return POLICIES.names()


def policy_class(name: str) -> type[Policy]:
    return POLICIES.policy_class(name)


def policy_config_class(name: str) -> type[PolicyConfig]:
    return POLICIES.config_class(name)


def make_policy(config: PolicyConfig, data: StoreInfo) -> Policy:
    """A fresh policy of `config`'s registered type for training data `data` (`Policy.from_data`)."""
    return POLICIES.policy_class(config.type).from_data(config, data)


def load_policy(directory: str | Path, map_location: Any = "cpu") -> Policy:
    """Load a saved policy of whichever registered type its config.json names."""
    path = Path(directory) / CONFIG_FILE
    if not path.exists():
        raise FileNotFoundError(f"{directory} is not a saved policy (no {CONFIG_FILE})")
    name = json.loads(path.read_text()).get("type")
    if name is None:
        raise ValueError(f"{path} names no policy type (no 'type' key)")
    return POLICIES.policy_class(name).from_pretrained(directory, map_location=map_location)
