"""`--init-from FOLDER`: start training from a saved policy's weights instead of a fresh initialisation (the
fine-tuning of a pretrained generalist, `gazereg pretrain`'s `policy/`); `--train.init-from` in
`gazereg experiment`, where every arm starts from it.

    gazereg train --preset quick --data.store runs/ft/demos --init-from runs/pretrain/policy ...

    pre = read_init(folder, "vla")                  # refused: not a saved policy, another policy type
    policy = init_policy(cfg.policy, data, pre, f)  # this run's architecture, `pre`'s tokenizer and weights

The run's policy is built from its own `--policy` config resolved from its data (as a run from scratch
builds it, so a fine-tuned and a from-scratch run of one config have the same architecture), with the saved
policy's tokenizer, and then takes every saved parameter and buffer: the weights at step 0 are the saved
ones, bit for bit.

- Tokenizer: the saved one (tokenizer.json), never one rebuilt from the fine-tuning data: a "words"
  vocabulary rebuilt from other instructions would give the same words other ids (or other shapes).
- Normalisation: the saved state/action mean and std (buffers in model.safetensors) are kept, not refitted on
  the fine-tuning data. Meta-World's state (hand xyz, gripper) and action (dx, dy, dz, grip) spaces are the
  same for every task, and the pretrained layers map normalised inputs to normalised actions: refitting
  would change the function the pretrained weights compute before the first step, and 10 demonstrations
  give noisy statistics. A policy fine-tuned on a simulator with other state or action units should be
  trained from scratch instead.

Refused before the first step (`UsageError`, one line, exit 2): a folder that is not a saved policy
(model.safetensors, config.json and tokenizer.json) or whose weights do not read, a policy of another type
than `--policy.type`, parameter shapes that differ from this run's (the first mismatching tensor named with
both shapes: another width, depth, chunk, text length, state or action size), and any other config field
that differs (e.g. `--policy.tokenizer`), listed. A resumed fine-tuning run reads the folder again (its
checkpoint then replaces the weights), so keep it; `init_from.json` in the run folder records its path and
the SHA-256 of its model.safetensors.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from torch import Tensor

from gazereg.data.dataset import StoreInfo
from gazereg.policies import Policy, PolicyConfig, policy_class
from gazereg.policies.base import CONFIG_FILE, MODEL_FILE, TOKENIZER_FILE
from gazereg.runtime.config import option
from gazereg.runtime.errors import UsageError, one_line
from gazereg.runtime.io import atomic_write_json

INIT_RECORD = "init_from.json"
"""what a run folder started from a saved policy records of it"""
FREE_FIELDS = ("camera_hw",)
"""config fields a fine-tuning run may have other values of: the stored frame size (frames are resized to the
policy's input size)"""


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def read_init(folder: Path, policy_type: str, flag: str = option("init_from")) -> Policy:
    """The saved policy in `folder` (on the CPU); UsageError naming `flag` when it is not a saved policy, is
    damaged or holds another type than `policy_type`."""
    if not folder.is_dir():
        raise UsageError(
            f"{flag} {folder}: no such folder (give a saved policy folder, e.g. runs/pretrain/policy)"
        )
    missing = [f for f in (MODEL_FILE, CONFIG_FILE, TOKENIZER_FILE) if not (folder / f).is_file()]
    if missing:
        raise UsageError(
            f"{flag} {folder} is not a saved policy: {', '.join(missing)} missing (a policy folder holds "
            f"{MODEL_FILE}, {CONFIG_FILE} and {TOKENIZER_FILE}, e.g. runs/pretrain/policy)"
        )
    try:
        saved_type = json.loads((folder / CONFIG_FILE).read_text()).get("type")
    except (ValueError, AttributeError, OSError) as e:
        raise UsageError(
            f"{flag} {folder}: {CONFIG_FILE} does not read as a policy config ({one_line(e)})"
        ) from None
    if saved_type != policy_type:
        raise UsageError(
            f"{flag} {folder} holds a {saved_type!r} policy, but this run trains --policy.type {policy_type}"
        )
    try:
        return policy_class(policy_type).from_pretrained(folder)
    except UsageError:
        raise
    except (ValueError, KeyError, TypeError, OSError, RuntimeError) as e:
        raise UsageError(f"{flag} {folder}: the saved policy does not load ({one_line(e)})") from None


def first_shape_mismatch(mine: Mapping[str, Tensor], saved: Mapping[str, Tensor]) -> str | None:
    """The first difference, in this run's parameter order, between two state dicts' names and shapes, as
    text; None when every name and shape agrees."""
    for name, t in mine.items():
        if name not in saved:
            return f"{name} {tuple(t.shape)} is not in the saved policy"
        if tuple(saved[name].shape) != tuple(t.shape):
            return (
                f"{name} is {tuple(saved[name].shape)} in the saved policy but {tuple(t.shape)} in this run"
            )
    extra = [name for name in saved if name not in mine]
    return f"{extra[0]} {tuple(saved[extra[0]].shape)} is not in this run's policy" if extra else None


def config_differences(mine: PolicyConfig, saved: PolicyConfig) -> list[str]:
    """`--policy.FIELD value (saved: value)` for every config field but FREE_FIELDS that differs."""
    a, b = mine.to_dict(), saved.to_dict()
    return [
        f"{option('policy.' + k)} {a.get(k)!r} (saved: {b.get(k)!r})"
        for k in sorted(set(a) | set(b))
        if k not in FREE_FIELDS and a.get(k) != b.get(k)
    ]


def init_policy(config: PolicyConfig, data: StoreInfo, saved: Policy, folder: Path) -> Policy:
    """A policy of this run's `config` resolved from `data`, with `saved`'s tokenizer, weights and
    normalisation statistics (module docstring); UsageError when they do not fit."""
    flag = f"{option('init_from')} {folder}"
    base_fields = PolicyConfig.data_fields(saved.config)
    own = {k: v for k, v in saved.config.data_fields().items() if k not in base_fields}
    resolved = dataclasses.replace(config.resolve(data), **own)  # e.g. the VLA's vocab_size: the tokenizer's
    try:
        policy = type(saved)(resolved, saved.tokenizer)
    except ValueError as e:
        raise UsageError(
            f"{flag}: this run's policy config does not fit the saved one ({one_line(e)})"
        ) from None
    mismatch = first_shape_mismatch(policy.state_dict(), saved.state_dict())
    if mismatch is not None:
        raise UsageError(
            f"{flag}: parameter shapes differ: {mismatch}; give this run the saved policy's config"
        )
    differ = config_differences(policy.config, saved.config)
    if differ:
        raise UsageError(f"{flag}: the policy config differs from the saved one: {'; '.join(differ)}")
    policy.load_state_dict(saved.state_dict())
    return policy


def init_record(folder: Path, saved: Policy) -> dict[str, Any]:
    """What a run records of the policy it started from: path, type, SHA-256 of its weights file."""
    return {"path": str(folder), "type": saved.name, "model_sha256": file_sha256(folder / MODEL_FILE)}


def write_init_record(run_dir: Path, record: dict[str, Any]) -> None:
    atomic_write_json(run_dir / INIT_RECORD, record)
