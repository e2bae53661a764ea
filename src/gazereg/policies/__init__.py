"""Policies: a registry of policy classes and the `make_policy` / `load_policy` factories.

A registered policy class provides `config_class`, `__init__(config, tokenizer)`, `forward(batch, ...) ->
(loss, info)`, `gaze_probe_spec(camera, layers)`, `geometry(camera)`, `select_action(observation,
instruction)`, `reset()`, `save_pretrained(dir)` and `from_pretrained(dir)`.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path
from typing import Any

# name -> "module:Class"; classes import on first use.
_REGISTRY: dict[str, str | type] = {"vla": "gazereg.policies.vla.modeling_vla:VLAPolicy"}


def register_policy(name: str, cls: type | str) -> None:
    """Register a policy class (or a lazy "module:Class" path) under `name`."""
    _REGISTRY[name] = cls


def available_policies() -> list[str]:
    return sorted(_REGISTRY)


def get_policy_class(name: str) -> type:
    if name not in _REGISTRY:
        raise KeyError(f"unknown policy {name!r}; registered: {available_policies()}")
    entry = _REGISTRY[name]
    if isinstance(entry, str):
        module, attr = entry.split(":")
        entry = getattr(importlib.import_module(module), attr)
        _REGISTRY[name] = entry
    return entry


def make_policy(name: str = "vla", config: Any = None, **kwargs: Any) -> Any:
    """Build a fresh policy: `make_policy("vla", config, tokenizer=tok)` (config resolved from the data)."""
    cls = get_policy_class(name)
    config = cls.config_class() if config is None else config
    return cls(config, **kwargs)


def load_policy(directory: str | Path, map_location: str = "cpu") -> Any:
    """Load a saved policy of whichever registered type its config.json names."""
    path = Path(directory) / "config.json"
    if not path.exists():
        raise FileNotFoundError(f"{directory} is not a saved policy (no config.json)")
    name = json.loads(path.read_text()).get("type", "vla")
    return get_policy_class(name).from_pretrained(directory, map_location=map_location)


__all__ = ["available_policies", "get_policy_class", "load_policy", "make_policy", "register_policy"]
