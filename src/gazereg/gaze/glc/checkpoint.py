"""Safe loading and saving of GLC weights.

* `load_glc_checkpoint(model, path)`: official SlowFast-style `.pyth`/`.pt` files (a dict whose
  `model_state` holds the state dict, names possibly prefixed `module.` by DDP), read with
  `torch.load(weights_only=True)` (no pickled code runs), a bare state dict, or a `.safetensors` file.
  Loading is strict: any missing, unexpected or mis-shaped entry raises `CheckpointMismatchError`
  listing all of them.
* `save_glc(model, cfg, folder)` / `load_glc(folder)`: our own format, `model.safetensors` +
  `config.json`, each written atomically.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file

from gazereg.gaze.glc.model import GLC, GLCConfig
from gazereg.runtime.io import atomic_path

WEIGHTS_NAME = "model.safetensors"
CONFIG_NAME = "config.json"
_PREFIXES = ("module.", "model.")


class CheckpointMismatchError(RuntimeError):
    """A checkpoint's entries do not match the model; `missing`, `unexpected` and `mismatched` list them."""

    def __init__(
        self,
        missing: list[str],
        unexpected: list[str],
        mismatched: list[tuple[str, tuple[int, ...], tuple[int, ...]]],
        source: str = "",
    ) -> None:
        self.missing, self.unexpected, self.mismatched = missing, unexpected, mismatched
        where = f" {source}" if source else ""
        lines = [f"checkpoint{where} does not match the model:"]
        lines.append(f"  missing ({len(missing)}): {missing}")
        lines.append(f"  unexpected ({len(unexpected)}): {unexpected}")
        shapes = [f"{k}: checkpoint {tuple(a)} vs model {tuple(b)}" for k, a, b in mismatched]
        lines.append(f"  mis-shaped ({len(mismatched)}): {shapes}")
        super().__init__("\n".join(lines))


def read_state_dict(path: str | Path) -> dict[str, torch.Tensor]:
    """Read the tensors of a checkpoint file without executing pickled code.

    `.safetensors` files are read with safetensors; anything else with `torch.load(weights_only=True)`.
    A dict with a `model_state` (SlowFast) or `state_dict` entry is unwrapped; a leading `module.`
    prefix (DDP) is removed from every name when all names carry it.
    """
    path = Path(path)
    if path.suffix == ".safetensors":
        sd: Mapping = load_file(str(path), device="cpu")
    else:
        obj = torch.load(path, map_location="cpu", weights_only=True)
        if not isinstance(obj, Mapping):
            raise TypeError(f"{path}: expected a dict, got {type(obj).__name__}")
        sd = obj
        for key in ("model_state", "state_dict", "model"):
            if key in obj and isinstance(obj[key], Mapping):
                sd = obj[key]
                break
    sd = {k: v for k, v in sd.items() if isinstance(v, torch.Tensor)}
    for prefix in _PREFIXES:
        if sd and all(k.startswith(prefix) for k in sd):
            sd = {k[len(prefix) :]: v for k, v in sd.items()}
    return dict(sd)


def check_state_dict(
    model: torch.nn.Module, state_dict: Mapping[str, torch.Tensor], source: str = ""
) -> None:
    """Raise `CheckpointMismatchError` unless names and shapes match `model.state_dict()` exactly."""
    own = model.state_dict()
    missing = sorted(set(own) - set(state_dict))
    unexpected = sorted(set(state_dict) - set(own))
    mismatched = [
        (k, tuple(state_dict[k].shape), tuple(own[k].shape))
        for k in sorted(set(own) & set(state_dict))
        if tuple(state_dict[k].shape) != tuple(own[k].shape)
    ]
    if missing or unexpected or mismatched:
        raise CheckpointMismatchError(missing, unexpected, mismatched, source)


def load_glc_checkpoint(model: torch.nn.Module, path: str | Path) -> torch.nn.Module:
    """Load weights from `path` into `model` strictly (see module docstring); returns `model`."""
    sd = read_state_dict(path)
    check_state_dict(model, sd, source=str(path))
    model.load_state_dict(sd, strict=True)
    return model


def save_glc(model: GLC, cfg: GLCConfig | None, folder: str | Path) -> Path:
    """Write `folder/model.safetensors` and `folder/config.json` (each atomically); returns `folder`."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cfg = cfg if cfg is not None else model.cfg
    tensors = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    with atomic_path(folder / WEIGHTS_NAME) as tmp:
        # one metadata key: safetensors writes the metadata map in arbitrary order, and the `glc` source
        # records this file's SHA-256, which must not change when the same weights are saved again
        save_file(tensors, str(tmp), metadata={"format": "pt"})
    with atomic_path(folder / CONFIG_NAME) as tmp:
        tmp.write_text(cfg.to_json() + "\n")
    return folder


def load_glc(folder: str | Path, device: str | torch.device = "cpu") -> GLC:
    """Build a `GLC` from `folder/config.json` and load `folder/model.safetensors` strictly."""
    folder = Path(folder)
    cfg = GLCConfig.from_dict(json.loads((folder / CONFIG_NAME).read_text()))
    model = GLC(cfg)
    load_glc_checkpoint(model, folder / WEIGHTS_NAME)
    return model.to(device)
