"""Training checkpoints without pickle: tensors in safetensors, structure in JSON, written atomically.

    run_dir/checkpoints/step_000100/
      model.safetensors, config.json, tokenizer.json   the policy to evaluate (EMA weights when EMA is on);
                                                        loads with Policy.from_pretrained, no training state
      training_state/
        state.json                                      step, epoch, the resolved training config
        model_raw.safetensors                           the raw (non-EMA) weights, only when EMA is on
        optimizer.safetensors + optimizer.json          optimizer tensors + param groups and scalars
        scheduler.json                                  LR scheduler state
        rng.safetensors + rng.json                      torch (CPU and CUDA), numpy and python RNG states
        aux_NAME.safetensors                            training-only modules outside the policy, e.g. the
                                                        location control's head (gazereg.training.location)

The whole step folder is written under a temporary name and renamed, so a checkpoint exists completely or
not at all; `latest_checkpoint` therefore never returns a half-written one. Its files get the mode an ordinary
write gives (0666 / 0777 less the umask) and equal states give byte-identical files (sorted safetensors
headers, `gazereg.runtime.io.save_safetensors`). A full disk while saving raises `CheckpointNotSaved`, one line
naming the folder, with the previous checkpoints untouched. A checkpoint damaged afterwards (a
truncated copy, a full disk) raises `DamagedCheckpoint` naming the file when read (`read_checkpoint` reads every
file before anything is restored); `read_resumable` then falls back to the previous readable checkpoint with
a logged warning.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import random
import re
import shutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import torch
from safetensors import SafetensorError
from torch import Tensor

from gazereg.policies import Policy
from gazereg.policies.base import CONFIG_FILE
from gazereg.runtime.io import DamagedFile, atomic_dir, disk_full, load_safetensors, save_safetensors

log = logging.getLogger(__name__)

STEP_RE = re.compile(r"^step_(\d{6,})$")
STATE_DIR = "training_state"
T = TypeVar("T")


class DamagedCheckpoint(ValueError):
    """A file of a checkpoint cannot be read (truncated, corrupted or missing); the message names it."""


class CheckpointNotSaved(OSError):
    """A checkpoint could not be written (its disk is full); the message names the folder and says that the
    previous checkpoints are kept."""


def checkpoint_dir(run_dir: str | Path, step: int) -> Path:
    return Path(run_dir) / "checkpoints" / f"step_{step:06d}"


def list_checkpoints(run_dir: str | Path) -> list[tuple[int, Path]]:
    base = Path(run_dir) / "checkpoints"
    if not base.exists():
        return []
    out = []
    for p in base.iterdir():
        m = STEP_RE.match(p.name)
        if m and (p / STATE_DIR / "state.json").exists():
            out.append((int(m.group(1)), p))
    return sorted(out)


def latest_checkpoint(run_dir: str | Path) -> Path | None:
    cks = list_checkpoints(run_dir)
    return cks[-1][1] if cks else None


def prune_checkpoints(run_dir: str | Path, keep: int) -> None:
    """Delete all but the `keep` newest checkpoints (keep <= 0 keeps everything)."""
    if keep <= 0:
        return
    for _, p in list_checkpoints(run_dir)[:-keep]:
        shutil.rmtree(p, ignore_errors=True)


# ----- optimizer state ------------------------------------------------------------------------------------
def _jsonable(x: Any) -> Any:
    if isinstance(x, tuple | list):
        return [_jsonable(v) for v in x]
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, np.generic):
        return x.item()
    return x


def split_state(sd: Mapping[str, Any], prefix: str = "") -> tuple[dict[str, Tensor], Any]:
    """Nested state dict -> (flat tensors, JSON structure with {"__tensor__": key} placeholders)."""
    tensors: dict[str, Tensor] = {}

    def walk(x: Any, path: str) -> Any:
        if isinstance(x, Tensor):
            tensors[path] = x.detach().cpu().contiguous()
            return {"__tensor__": path}
        if isinstance(x, dict):
            return {
                "__dict__": [
                    [walk(k, f"{path}.k{i}") if isinstance(k, Tensor) else k, walk(v, f"{path}.{k}")]
                    for i, (k, v) in enumerate(x.items())
                ]
            }
        if isinstance(x, tuple | list):
            return {
                "__list__": [walk(v, f"{path}.{i}") for i, v in enumerate(x)],
                "tuple": isinstance(x, tuple),
            }
        return _jsonable(x)

    return tensors, walk(dict(sd), prefix or "s")


def join_state(tensors: Mapping[str, Tensor], structure: Any) -> Any:
    """Inverse of split_state (dict keys keep their JSON type: ints stay ints)."""

    def walk(x: Any) -> Any:
        if isinstance(x, dict):
            if "__tensor__" in x:
                return tensors[x["__tensor__"]]
            if "__dict__" in x:
                return {k: walk(v) for k, v in x["__dict__"]}
            if "__list__" in x:
                items = [walk(v) for v in x["__list__"]]
                return tuple(items) if x.get("tuple") else items
        return x

    return walk(structure)


def save_tensors_json(directory: Path, name: str, sd: Mapping[str, Any]) -> None:
    tensors, structure = split_state(sd)
    save_safetensors(tensors, directory / f"{name}.safetensors")
    (directory / f"{name}.json").write_text(json.dumps(structure) + "\n")


def load_tensors_json(directory: Path, name: str, device: str = "cpu") -> Any:
    tensors = load_safetensors(directory / f"{name}.safetensors", device=device)
    return join_state(tensors, json.loads((directory / f"{name}.json").read_text()))


# ----- RNG ------------------------------------------------------------------------------------------------
def rng_state() -> dict[str, Any]:
    np_state = np.random.get_state()
    state: dict[str, Any] = {
        "torch": torch.get_rng_state(),
        "numpy": {
            "name": np_state[0],
            "keys": torch.from_numpy(np_state[1].astype(np.int64)),
            "pos": int(np_state[2]),
            "has_gauss": int(np_state[3]),
            "cached_gaussian": float(np_state[4]),
        },
        "python": random.getstate(),
    }
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: Mapping[str, Any]) -> None:
    torch.set_rng_state(state["torch"].to(torch.uint8))
    n = state["numpy"]
    np.random.set_state(
        (n["name"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached_gaussian"])
    )
    py = state["python"]
    random.setstate((py[0], tuple(py[1]), py[2]))
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all([s.to(torch.uint8) for s in state["cuda"]])


# ----- whole checkpoints ----------------------------------------------------------------------------------
def save_checkpoint(
    run_dir: str | Path,
    step: int,
    policy: Policy,
    optimizer: torch.optim.Optimizer,
    scheduler: Any,
    state: Mapping[str, Any],
    eval_state_dict: Mapping[str, Tensor] | None = None,
    aux: Mapping[str, Mapping[str, Tensor]] | None = None,
) -> Path:
    """Write checkpoints/step_XXXXXX atomically. `policy` supplies the raw weights (and writes the pretrained
    files); `eval_state_dict` (EMA weights) goes into model.safetensors instead when given; `aux` maps names
    to the state dicts of training-only modules (training_state/aux_NAME.safetensors)."""
    path = checkpoint_dir(run_dir, step)
    try:
        _write_checkpoint(path, step, policy, optimizer, scheduler, state, eval_state_dict, aux)
    except (OSError, SafetensorError) as e:
        if not disk_full(e):
            raise
        kept = [p.name for _, p in list_checkpoints(run_dir)]
        previous = f"the previous checkpoint ({kept[-1]}) is kept" if kept else "no checkpoint was written"
        raise CheckpointNotSaved(
            f"no space left on {path.parent} while saving checkpoint {path.name}; {previous}. Free space and "
            "resume with --resume"
        ) from e
    return path


def _write_checkpoint(
    path: Path,
    step: int,
    policy: Policy,
    optimizer: torch.optim.Optimizer,
    scheduler: Any,
    state: Mapping[str, Any],
    eval_state_dict: Mapping[str, Tensor] | None,
    aux: Mapping[str, Mapping[str, Tensor]] | None,
) -> None:
    with atomic_dir(path) as tmp:
        policy.write_pretrained(tmp, eval_state_dict)
        ts = tmp / STATE_DIR
        ts.mkdir()
        if eval_state_dict is not None:
            save_safetensors(
                {k: v.detach().cpu().contiguous() for k, v in policy.state_dict().items()},
                ts / "model_raw.safetensors",
            )
        save_tensors_json(ts, "optimizer", optimizer.state_dict())
        sched = {k: v for k, v in scheduler.state_dict().items() if k != "lr_lambdas"}
        (ts / "scheduler.json").write_text(json.dumps(_jsonable(sched), sort_keys=True) + "\n")
        save_tensors_json(ts, "rng", rng_state())
        for name, sd in (aux or {}).items():
            tensors = {k: v.detach().cpu().contiguous() for k, v in sd.items()}
            save_safetensors(tensors, ts / f"aux_{name}.safetensors")
        (ts / "state.json").write_text(
            json.dumps(_jsonable({**state, "step": step}), indent=2, sort_keys=True) + "\n"
        )


@dataclass
class CheckpointData:
    """Everything a checkpoint holds, read into memory (nothing restored yet)."""

    path: Path
    state: dict[str, Any]
    """state.json: step, epoch, steps, the resolved training config, ..."""
    policy_type: str | None
    """the policy type recorded in the pretrained config.json"""
    model: dict[str, Tensor]
    """the raw (non-EMA) weights"""
    ema: dict[str, Tensor] | None
    """the EMA weights (model.safetensors) when the checkpoint holds them"""
    optimizer: Any
    scheduler: dict[str, Any]
    rng: Any
    aux: dict[str, dict[str, Tensor]] = dataclasses.field(default_factory=dict)
    """training-only modules' weights by name (`save_checkpoint`'s aux)"""


def _read(file: Path, reader: Callable[[Path], T]) -> T:
    """reader(file), with any failure to read it raised as DamagedCheckpoint naming the file."""
    try:
        return reader(file)
    except DamagedFile as e:  # a safetensors file: the message says what is wrong with it
        what = str(e).removeprefix(f"{file} ")
        raise DamagedCheckpoint(f"checkpoint file {file} cannot be read: it {what}") from e
    except (OSError, ValueError, KeyError, TypeError, SafetensorError) as e:
        raise DamagedCheckpoint(f"checkpoint file {file} cannot be read ({type(e).__name__}: {e})") from e


def _read_json(file: Path) -> Any:
    return json.loads(file.read_text())


def _read_tensors(file: Path) -> dict[str, Tensor]:
    return load_safetensors(
        file, advice="re-save or retrain (--resume falls back to the previous checkpoint)"
    )


def _read_split(directory: Path, name: str) -> Any:
    """A state saved by `save_tensors_json`, each of its two files named when it cannot be read."""
    tensors = _read(directory / f"{name}.safetensors", _read_tensors)
    structure = _read(directory / f"{name}.json", _read_json)
    return _read(directory / f"{name}.json", lambda _: join_state(tensors, structure))


def read_checkpoint(path: str | Path) -> CheckpointData:
    """Read every file of a training checkpoint; FileNotFoundError when `path` is not one, DamagedCheckpoint
    naming the first file that cannot be read."""
    path = Path(path)
    ts = path / STATE_DIR
    if not (ts / "state.json").exists():
        raise FileNotFoundError(f"{path} is not a training checkpoint (no {STATE_DIR}/state.json)")
    state = _read(ts / "state.json", _read_json)
    if not isinstance(state, dict) or "step" not in state:
        raise DamagedCheckpoint(f"checkpoint file {ts / 'state.json'} has no step")
    pretrained = _read(path / CONFIG_FILE, _read_json)
    model = _read(path / "model.safetensors", _read_tensors)
    ema = None
    if (ts / "model_raw.safetensors").exists():
        ema, model = model, _read(ts / "model_raw.safetensors", _read_tensors)
    return CheckpointData(
        path=path,
        state=state,
        policy_type=pretrained.get("type") if isinstance(pretrained, dict) else None,
        model=model,
        ema=ema,
        optimizer=_read_split(ts, "optimizer"),
        scheduler=_read(ts / "scheduler.json", _read_json),
        rng=_read_split(ts, "rng"),
        aux={f.stem[4:]: _read(f, _read_tensors) for f in sorted(ts.glob("aux_*.safetensors"))},
    )


def read_resumable(run_dir: str | Path) -> CheckpointData | None:
    """The newest checkpoint of a run that reads completely (None when the run has none). A damaged newer one
    is skipped with a logged warning; when none reads, the newest one's DamagedCheckpoint is raised."""
    first_error: DamagedCheckpoint | None = None
    for _, path in reversed(list_checkpoints(run_dir)):
        try:
            data = read_checkpoint(path)
        except DamagedCheckpoint as e:
            first_error = first_error or e
            log.warning("%s; falling back to the previous checkpoint", e)
            continue
        return data
    if first_error is not None:
        raise first_error
    return None


def restore_checkpoint(
    data: CheckpointData,
    policy: Policy,
    optimizer: torch.optim.Optimizer,
    scheduler: Any,
    restore_rng: bool = True,
) -> dict[str, Any]:
    """Restore raw weights, optimizer, scheduler (and RNG) from a read checkpoint; returns state.json (with the
    EMA state dict under 'ema_state_dict' when the checkpoint holds one)."""
    state = dict(data.state)
    if data.ema is not None:
        state["ema_state_dict"] = data.ema
    policy.load_state_dict(data.model)
    optimizer.load_state_dict(data.optimizer)
    scheduler.load_state_dict({**scheduler.state_dict(), **data.scheduler})
    if restore_rng:
        set_rng_state(data.rng)
    return state


def load_checkpoint(
    path: str | Path,
    policy: Policy,
    optimizer: torch.optim.Optimizer,
    scheduler: Any,
    restore_rng: bool = True,
) -> dict[str, Any]:
    """`read_checkpoint` then `restore_checkpoint`: restore a checkpoint into the policy, optimizer, scheduler
    (and RNG); returns state.json (with 'ema_state_dict' when the checkpoint holds EMA weights)."""
    return restore_checkpoint(read_checkpoint(path), policy, optimizer, scheduler, restore_rng)
