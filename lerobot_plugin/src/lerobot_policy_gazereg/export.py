"""Turn a gaze-trained checkpoint into a plain LeRobot one that stock LeRobot loads, without this plugin.

    python -m lerobot_policy_gazereg.export CKPT_DIR OUT_DIR
    # e.g. CKPT_DIR = outputs/run/checkpoints/last/pretrained_model (or its parent checkpoint folder)

A `<base>_gaze` policy (`smolvla_gaze`, `pi0_gaze`, `pi05_gaze`) holds exactly `<base>`'s parameters; only its
config differs. OUT_DIR gets:
- config.json with `"type": "<base>"` and the fields `<base>`'s config does not know (the gaze_* options) removed;
- train_config.json (when present) with the same change to its `policy` section;
- the pre/post-processor files, minus any step whose registry name is a gaze step (stock LeRobot cannot resolve
  one; the gaze steps only carry training-time gaze data);
- every other file (model.safetensors, processor state files, ...) copied unchanged.
OUT_DIR is written in a temporary folder beside it and renamed into place, so it is complete or absent.

    from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy
    policy = SmolVLAPolicy.from_pretrained(OUT_DIR)
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gazereg.runtime.errors import UsageError, report_errors, split_verbose

GAZE_SUFFIX = "_gaze"
CONFIG_NAME = "config.json"
TRAIN_CONFIG_NAME = "train_config.json"


@dataclass(frozen=True)
class ExportResult:
    """What `export_plain_checkpoint` wrote."""

    out_dir: Path
    gaze_type: str  # e.g. "smolvla_gaze"
    base_type: str  # e.g. "smolvla"
    dropped_fields: tuple[str, ...]  # config fields the base config does not know (the gaze_* options)
    dropped_steps: tuple[str, ...]  # "<processor file>:<registry name>" of removed gaze processor steps


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise UsageError(f"{path} is not readable JSON: {e}") from e


def _checkpoint_dir(path: Path) -> Path:
    """The folder holding config.json: `path` itself or its `pretrained_model/` (a lerobot-train step folder)."""
    if not path.is_dir():
        raise UsageError(f"{path} is not a folder (expected a gaze checkpoint's pretrained_model folder)")
    for cand in (path, path / "pretrained_model"):
        if (cand / CONFIG_NAME).is_file():
            return cand
    raise UsageError(
        f"{path} is not a LeRobot checkpoint: no {CONFIG_NAME} in it or in its pretrained_model/"
    )


def base_policy_type(policy_type: object, where: Path) -> str:
    """`<base>` of a `<base>_gaze` policy type, checked to be a policy type stock LeRobot registers."""
    if not isinstance(policy_type, str) or not policy_type.endswith(GAZE_SUFFIX):
        raise UsageError(f"{where} is not a gaze checkpoint: its type is {policy_type!r}, not '<base>_gaze'")
    base = policy_type[: -len(GAZE_SUFFIX)]
    import lerobot.policies  # noqa: F401  (registers every stock policy config)
    from lerobot.configs import PreTrainedConfig

    if base not in PreTrainedConfig.get_known_choices():
        raise UsageError(
            f"{where}: type {policy_type!r} maps to {base!r}, which is not a LeRobot policy type"
        )
    return base


def plain_policy_config(cfg: dict[str, Any], base: str) -> tuple[dict[str, Any], tuple[str, ...]]:
    """A policy config dict (config.json) retyped to `base`, minus the fields `base`'s config lacks."""
    from lerobot.configs import PreTrainedConfig

    known = {f.name for f in dataclasses.fields(PreTrainedConfig.get_choice_class(base))}
    dropped = tuple(k for k in cfg if k != "type" and k not in known)
    plain = {k: v for k, v in cfg.items() if k not in dropped}
    plain["type"] = base
    return plain, dropped


def _plain_pipeline(pipe: dict[str, Any], name: str) -> tuple[dict[str, Any], list[str]]:
    """A saved processor pipeline (json with "steps") without its gaze steps."""
    keep, dropped = [], []
    for step in pipe["steps"]:
        reg = step.get("registry_name") if isinstance(step, dict) else None
        if isinstance(reg, str) and "gaze" in reg.lower():
            dropped.append(f"{name}:{reg}")
        else:
            keep.append(step)
    return {**pipe, "steps": keep}, dropped


def _write_json(path: Path, obj: Any) -> None:
    path.write_text(json.dumps(obj, indent=4) + "\n")


def _convert_into(src: Path, tmp: Path, base: str, cfg: dict[str, Any]) -> tuple[tuple[str, ...], list[str]]:
    """Copy `src`'s files into `tmp`, rewriting the configs and processor pipelines for `base`."""
    plain, dropped_fields = plain_policy_config(cfg, base)
    dropped_steps: list[str] = []
    for f in sorted(src.iterdir()):
        if f.is_dir():
            continue  # a pretrained_model folder is flat; nothing below it belongs to the policy
        dst = tmp / f.name
        if f.name == CONFIG_NAME:
            _write_json(dst, plain)
        elif f.name == TRAIN_CONFIG_NAME:
            train = _read_json(f)
            if isinstance(train, dict) and isinstance(train.get("policy"), dict):
                train["policy"] = plain_policy_config(train["policy"], base)[0]
            _write_json(dst, train)
        elif (
            f.suffix == ".json"
            and isinstance(pipe := _read_json(f), dict)
            and isinstance(pipe.get("steps"), list)
        ):
            new, gone = _plain_pipeline(pipe, f.name)
            dropped_steps += gone
            _write_json(dst, new)
        else:
            shutil.copy2(f, dst)
    return dropped_fields, dropped_steps


def export_plain_checkpoint(ckpt_dir: str | Path, out_dir: str | Path) -> ExportResult:
    """Write `out_dir` as a plain `<base>` checkpoint of the `<base>_gaze` checkpoint `ckpt_dir`.

    Raises UsageError (one line) when `ckpt_dir` is not a gaze checkpoint or `out_dir` is not empty.
    """
    src = _checkpoint_dir(Path(ckpt_dir))
    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UsageError(f"{out} already exists and is not an empty folder; choose a new output folder")
    cfg = _read_json(src / CONFIG_NAME)
    if not isinstance(cfg, dict):
        raise UsageError(f"{src / CONFIG_NAME} is not a policy config (a JSON object)")
    base = base_policy_type(cfg.get("type"), src)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        dropped_fields, dropped_steps = _convert_into(src, tmp, base, cfg)
        if out.exists():
            out.rmdir()  # empty (checked above)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return ExportResult(out, cfg["type"], base, dropped_fields, tuple(dropped_steps))


def _main(argv: list[str]) -> int:
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m lerobot_policy_gazereg.export",
        description="Write a plain LeRobot checkpoint (smolvla, pi0, pi05) from a gaze-trained one.",
    )
    parser.add_argument("ckpt_dir", help="the gaze checkpoint's pretrained_model folder (or its parent)")
    parser.add_argument("out_dir", help="the new plain checkpoint folder (must not exist or be empty)")
    args = parser.parse_args(argv)
    r = export_plain_checkpoint(args.ckpt_dir, args.out_dir)
    dropped = ", ".join(r.dropped_fields) or "none"
    steps = f"; removed processor steps: {', '.join(r.dropped_steps)}" if r.dropped_steps else ""
    print(f"wrote {r.out_dir}: type {r.gaze_type} -> {r.base_type}; removed fields: {dropped}{steps}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args, verbose = split_verbose(list(sys.argv[1:] if argv is None else argv))
    return report_errors("lerobot_policy_gazereg.export", _main, args, verbose)


if __name__ == "__main__":
    sys.exit(main())
