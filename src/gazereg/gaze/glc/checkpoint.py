"""Safe loading and saving of GLC weights.

* `load_glc_checkpoint(model, path)`: official SlowFast-style `.pyth`/`.pt` files (a dict whose
  `model_state` holds the state dict, names possibly prefixed `module.` by DDP), read with
  `torch.load(weights_only=True)` (no pickled code runs), a bare state dict, or a `.safetensors` file.
  Loading is strict: any missing, unexpected or mis-shaped entry raises `CheckpointMismatchError`
  (its lists hold all of them; its message, one line, counts them and names the first of each).
  A file that is no weights file at all raises `NotAGLCCheckpoint`, one holding pickled code
  `PickledCodeError` (never loaded); all three are `UsageError`s, so `gazereg` refuses them in one line.
* `save_glc(model, cfg, folder)` / `load_glc(folder)`: our own format, `model.safetensors` +
  `config.json`, each written atomically.
"""

from __future__ import annotations

import json
import pickle
from collections.abc import Mapping
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file

from gazereg.gaze.glc.model import GLC, GLCConfig
from gazereg.runtime.errors import UsageError
from gazereg.runtime.io import atomic_path, save_safetensors

WEIGHTS_NAME = "model.safetensors"
CONFIG_NAME = "config.json"
_PREFIXES = ("module.", "model.")


class NotAGLCCheckpoint(UsageError):
    """A file given as GLC weights that is not GLC weights (one line naming the file and what it is not)."""


class PickledCodeError(NotAGLCCheckpoint, pickle.UnpicklingError):
    """A checkpoint file whose pickle would run code (`torch.load(weights_only=True)` refused it)."""


class CheckpointMismatchError(NotAGLCCheckpoint):
    """A checkpoint's entries do not match the model; `missing`, `unexpected` and `mismatched` list them all,
    the message (one line) counts them and names the first of each."""

    def __init__(
        self,
        missing: list[str],
        unexpected: list[str],
        mismatched: list[tuple[str, tuple[int, ...], tuple[int, ...]]],
        source: str = "",
    ) -> None:
        self.missing, self.unexpected, self.mismatched = missing, unexpected, mismatched
        where = source or "the checkpoint"
        parts = []
        if missing:
            parts.append(f"{len(missing)} expected weights missing (first: {missing[0]!r})")
        if unexpected:
            parts.append(f"{len(unexpected)} unexpected (first: {unexpected[0]!r})")
        if mismatched:
            k, a, b = mismatched[0]
            parts.append(
                f"{len(mismatched)} mis-shaped (first: {k!r}, {tuple(a)} in the file, {tuple(b)} in the model)"
            )
        what = (
            "holds a GLC of another configuration"
            if not (missing or unexpected)
            else "is not a GLC checkpoint"
        )
        super().__init__(f"{where} {what}: {'; '.join(parts)}")


def read_state_dict(path: str | Path) -> dict[str, torch.Tensor]:
    """Read the tensors of a checkpoint file without executing pickled code.

    `.safetensors` files are read with safetensors; anything else with `torch.load(weights_only=True)`.
    A dict with a `model_state` (SlowFast) or `state_dict` entry is unwrapped; a leading `module.`
    prefix (DDP) is removed from every name when all names carry it. `PickledCodeError` for a pickle that
    would run code, `NotAGLCCheckpoint` for a file that is neither format (or holds no dict of tensors).
    """
    path = Path(path)
    if path.suffix == ".safetensors":
        try:
            sd: Mapping = load_file(str(path), device="cpu")
        except SafetensorError as e:
            raise NotAGLCCheckpoint(f"{path} is not a readable safetensors file ({_first_line(e)})") from None
    else:
        try:
            obj = torch.load(path, map_location="cpu", weights_only=True)
        except pickle.UnpicklingError as e:
            if str(e).startswith("Weights only load failed"):
                raise PickledCodeError(
                    f"{path} holds pickled code, which gazereg never loads; give a safetensors or "
                    "weights-only file"
                ) from None
            raise NotAGLCCheckpoint(f"{path} is not a torch weights file ({_first_line(e)})") from None
        except OSError:
            raise
        except (
            Exception
        ) as e:  # torch.load's ways of failing on other bytes: EOFError, KeyError, struct.error...
            detail = f": {_first_line(e)}" if isinstance(e, RuntimeError | ValueError) else ""
            raise NotAGLCCheckpoint(
                f"{path} is not a torch weights file (empty, truncated or another format{detail})"
            ) from None
        if not isinstance(obj, Mapping):
            raise NotAGLCCheckpoint(
                f"{path} is not a GLC checkpoint: it holds a {type(obj).__name__}, not a dict"
            )
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


def _first_line(error: BaseException) -> str:
    """An error's message cut to its first line and 120 characters (torch's run on for paragraphs)."""
    text = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
    return text if len(text) <= 120 else text[:117] + "..."


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
    # byte-identical for equal weights (the `glc` source records this file's SHA-256, which must not change
    # when the same weights are saved again) and with an ordinary file's mode
    save_safetensors(tensors, folder / WEIGHTS_NAME, metadata={"format": "pt"})
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
