"""The policy registry: policy type name -> `Policy` class, and the factories built on it.

    register_policy(MyPolicy)                  # under MyPolicy.config_class.type
    make_policy(config, data)                  # a fresh policy of config's registered type, resolved from data
    load_policy(folder)                        # whichever registered type the folder's config.json names
    policy_config_class("vla")                 # the config class `--policy.type vla` selects

The built-in policies are registered here. Another policy comes in one of two ways:

- as a plugin (the way to ship one): an installed package declares it in the entry-point group
  `gazereg.policies` (`mypolicy = "my_package.policy:MyPolicy"`, see `gazereg.policies.plugins`); a name
  nobody registered is looked up there, imported and registered, in whichever process asks for it, so
  `gazereg train --policy.type mypolicy`, `gazereg eval` and evaluation's spawned workers all know it;
- registered in code (`register_policy`), before a config naming it is parsed or a folder holding it is
  loaded. That registration is per process: processes that only import gazereg (evaluation's spawned
  workers when `workers > 1`, `accelerate launch -m gazereg.training.loop`) do not see it, so a policy
  registered this way runs only in processes that import the module registering it (or with `workers=1`).
"""

from __future__ import annotations

import json
import operator
from pathlib import Path
from typing import Any

from gazereg.data.dataset import StoreInfo
from gazereg.policies import plugins
from gazereg.policies.base import CONFIG_FILE, Policy, PolicyConfig
from gazereg.policies.vla.modeling_vla import VLAPolicy
from gazereg.runtime.config import Choice
from gazereg.runtime.errors import UsageError


class UnknownPolicy(UsageError, KeyError):
    """A policy type nobody registered or installed (a user mistake: `gazereg` exits 2 naming the known
    ones); a KeyError too, for callers that look names up."""

    __str__ = BaseException.__str__  # the message as given, not KeyError's quoted repr


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
        """The registered policy types and those installed plugins provide, sorted."""
        return sorted({*self._classes, *plugins.plugin_names()})

    def policy_class(self, name: str) -> type[Policy]:
        """The class of policy type `name`: registered, else loaded (and registered) from the installed
        plugin of that name (`gazereg.policies.plugins`)."""
        if name not in self._classes and (found := plugins.plugin_policy(name)) is not None:
            self.register(found)
        if name not in self._classes:
            raise UnknownPolicy(f"unknown policy type {name!r}; registered: {self.names()}")
        return self._classes[name]

    def config_class(self, name: str) -> type[PolicyConfig]:
        return self.policy_class(name).config_class


POLICIES = PolicyRegistry(VLAPolicy)
"""The process's policy registry (the built-ins; `register_policy` and installed plugins add more)."""

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
