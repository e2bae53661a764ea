"""Policies from installed packages: the `gazereg.policies` entry-point group.

A package that provides a policy declares it in its own pyproject.toml, with no code in gazereg naming it:

    [project.entry-points."gazereg.policies"]
    mypolicy = "my_package.policy:MyPolicy"        # the Policy subclass (or its PolicyConfig subclass)

The entry point's name is the policy's type (`MyPolicy.config_class.type`, `--policy.type mypolicy`). When
the registry (`gazereg.policies.registry`) is asked for a name nobody registered, it imports the entry
point of that name and registers the class; this happens in every process that looks the name up (the
`gazereg` commands, evaluation's spawned workers, `accelerate launch` ranks), so an installed plugin works
everywhere. A config class may be named instead of the policy class: the policy is then the one Policy
subclass of the config's module whose `config_class` it is.
"""

from __future__ import annotations

import sys
from importlib.metadata import EntryPoint, entry_points

from gazereg.policies.base import Policy, PolicyConfig

ENTRY_POINT_GROUP = "gazereg.policies"


def policy_entry_points() -> list[EntryPoint]:
    """The installed packages' entry points in the `gazereg.policies` group (name -> "module:Class")."""
    return list(entry_points(group=ENTRY_POINT_GROUP))


def plugin_names() -> list[str]:
    """The policy types installed packages provide, sorted."""
    return sorted({ep.name for ep in policy_entry_points()})


def plugin_policy(name: str) -> type[Policy] | None:
    """The Policy class the installed entry point `name` names (importing its module), or None when no
    installed package provides policy type `name`.

    Raises ImportError when the plugin's module fails to import, TypeError when the entry point names
    something else than a policy or a config class, or a policy of another type than `name`, and ValueError
    when several installed packages provide `name` differently."""
    found = {ep.value: ep for ep in policy_entry_points() if ep.name == name}
    if not found:
        return None
    if len(found) > 1:
        raise ValueError(
            f"policy type {name!r} is provided by several installed packages ({sorted(found)}); "
            f"uninstall all but one"
        )
    ep = next(iter(found.values()))
    where = f"the policy plugin {name} = {ep.value!r} (entry-point group {ENTRY_POINT_GROUP!r})"
    try:
        obj = ep.load()
    except Exception as e:
        raise ImportError(f"{where} failed to load: {type(e).__name__}: {e}") from e
    cls = _policy_of(obj, where)
    if cls.config_class.type != name:
        raise TypeError(
            f"{where} names a policy of type {cls.config_class.type!r}; the entry point's name must be its type"
        )
    return cls


def _policy_of(obj: object, where: str) -> type[Policy]:
    """`obj` when it is a Policy subclass; for a PolicyConfig subclass, the one Policy subclass of the
    config's module whose `config_class` is `obj`."""
    if isinstance(obj, type) and issubclass(obj, Policy):
        return obj
    if isinstance(obj, type) and issubclass(obj, PolicyConfig):
        module = vars(sys.modules[obj.__module__])
        users = {
            v
            for v in module.values()
            if isinstance(v, type) and issubclass(v, Policy) and v.config_class is obj
        }
        if len(users) == 1:
            return users.pop()
        raise TypeError(
            f"{where} names the config {obj.__name__}, but its module defines "
            f"{len(users) or 'no'} Policy classes using it; name the Policy class instead"
        )
    raise TypeError(f"{where} names {obj!r}, which is neither a Policy nor a PolicyConfig subclass")
