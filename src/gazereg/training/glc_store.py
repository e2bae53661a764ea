"""Train GLC on the gaze of an episode store, then evaluate it on the held-out episodes.

`train_glc_on_store(cfg)` learns from any episodes that carry per-frame gaze points: a gaze source's points
(`VisuomotorParams`: the simulated eye tracker), recorded `gaze_uv.<camera>` extras (`RecordedParams`), or
the peak of any other source's maps. Episodes are split deterministically
(`gazereg.gaze.glc.evaluate.holdout_split`: per task, every `holdout_every`-th is held out, or `holdout`
lists them), within the `tasks` named (all by default); with `heldout_tasks` it trains on every episode of
`tasks` and scores on episodes of those other tasks instead (`task_split`: a cross-fitted GLC's quality on
tasks it never saw). It writes, under `cfg.out`:

    run.json                  the resolved config, the split, the number of training clips
    checkpoints/, train_log.jsonl     `gazereg.training.glc.train_glc` (resumes from the newest checkpoint)
    final/                    model.safetensors, config.json, glc_train.json: the folder the `glc` gaze
                              source loads (`checkpoint=<out>/final`)
    eval.json                 `gazereg.gaze.glc.evaluate.evaluate_glc` on the held-out episodes
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from gazereg.data.store import EpisodeStore
from gazereg.gaze.glc.checkpoint import load_glc, load_glc_checkpoint, save_glc
from gazereg.gaze.glc.data import StoreClipDataset
from gazereg.gaze.glc.evaluate import (
    HoldoutSplit,
    evaluate_glc,
    gaze_points_source,
    holdout_split,
    indices_text,
    resolve_glc_folder,
)
from gazereg.gaze.glc.model import GLC
from gazereg.gaze.sources import GazeSourceParams
from gazereg.gaze.sources.glc import CONFIGS, GLCConfigName, GLCParams
from gazereg.gaze.sources.visuomotor import VisuomotorParams
from gazereg.runtime.config import Validated, option, require_choice, require_entries, require_number, to_dict
from gazereg.runtime.errors import UsageError
from gazereg.runtime.io import atomic_write_json, sweep_stale_temps
from gazereg.training.glc import GLCTrainConfig, train_glc

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GLCRunSettings(Validated):
    """Everything about a GLC training run but where its gaze comes from (shared by the library's
    `GLCStoreTrainConfig` and the command line's `GLCTrainCommand`); checked when built (`validate`)."""

    store: Path = Path("data/demos")
    """episode store with frames and per-frame gaze"""
    camera: str = "corner2"
    out: Path = Path("runs/glc")
    config: GLCConfigName = "small"
    """GLC size: small (96 px, 3.5 M params) | official (256 px, 70 M)"""
    init: Path | None = None
    """fine-tune from: a folder from `gazereg glc train` or an official GLC checkpoint; None = random init"""
    stride: int = 2
    """frames between a clip's frames"""
    clip_hop: int = 1
    """a training clip is centred on every clip_hop-th frame of each episode"""
    holdout_every: int = 5
    """within each task, every holdout_every-th episode (by index) is held out for evaluation"""
    holdout: tuple[int, ...] = ()
    """explicit held-out episode indices (overrides holdout_every)"""
    tasks: tuple[str, ...] = ()
    """train on the episodes of these tasks only (an episode's `task`, as the store names it); empty = all"""
    heldout_tasks: tuple[str, ...] = ()
    """evaluate on other tasks instead: every holdout_every-th episode of each of these tasks (from its first),
    none of them trained on, for the quality of a GLC that predicts tasks it never saw (needs `tasks`)"""
    device: str = "cpu"
    threads: int = 0
    """torch CPU threads (0: torch's default)"""
    optim: GLCTrainConfig = field(
        default_factory=lambda: GLCTrainConfig(
            steps=600, batch_size=8, lr=1e-3, warmup_steps=20, checkpoint_every=50, log_every=10
        )
    )
    evaluate: bool = True
    """evaluate on the held-out episodes after training (writes <out>/eval.json)"""
    resume: bool = True

    def validate(self, prefix: str) -> None:
        """UsageError naming the first bad option (the optimisation settings check their own)."""
        require_choice(self.config, prefix + "config", sorted(CONFIGS))
        require_number(self.stride, prefix + "stride", 1, integer=True)
        require_number(self.clip_hop, prefix + "clip_hop", 1, integer=True)
        if not self.holdout:
            require_number(self.holdout_every, prefix + "holdout_every", 2, integer=True)
        for index in self.holdout:
            require_number(index, prefix + "holdout", 0, integer=True)
        for name in ("tasks", "heldout_tasks"):
            require_entries(getattr(self, name), prefix + name, non_empty=False)
        if self.heldout_tasks and not self.tasks:
            raise UsageError(
                f"{option(prefix + 'heldout_tasks')} needs {option(prefix + 'tasks')}: the tasks to train on"
            )
        both = sorted(set(self.tasks) & set(self.heldout_tasks))
        if both:
            raise UsageError(
                f"{option(prefix + 'heldout_tasks')} lists training tasks ({option(prefix + 'tasks')}): "
                f"{', '.join(both)}"
            )
        if self.heldout_tasks and self.holdout:
            raise UsageError(f"{option(prefix + 'holdout')} and {option(prefix + 'heldout_tasks')}: give one")
        require_number(self.threads, prefix + "threads", 0, integer=True)


@dataclass(frozen=True)
class GLCStoreTrainConfig(GLCRunSettings):
    gaze: GazeSourceParams = field(default_factory=VisuomotorParams)
    """where the gaze points come from: `RecordedParams` (the `<key>.<camera>` extras themselves), the
    visuomotor source's eye trace, or any other source (the peak of its maps)"""


@dataclass(frozen=True)
class GLCStoreTrainResult:
    """What `train_glc_on_store` made."""

    final: Path
    """the trained model's folder, `<out>/final` (model.safetensors, config.json, glc_train.json)"""
    steps: int
    """optimizer steps done in all (counting a resumed run's)"""
    split: HoldoutSplit
    train_seconds: float
    """seconds this call spent training"""
    first_loss: float | None
    """the loss of this call's first step (None when it ran none)"""
    last_loss_mean10: float | None
    """the mean loss of this call's last 10 steps"""
    eval_path: Path | None = None
    """`<out>/eval.json`, when evaluated (`cfg.evaluate` and held-out episodes exist)"""
    eval_report: dict[str, Any] | None = None
    """its content: the report of `gazereg.gaze.glc.evaluate.evaluate_glc`"""


def _load_init(model: GLC, init: Path) -> None:
    folder = resolve_glc_folder(init)
    if folder is not None:
        src = load_glc(folder)
        if src.cfg != model.cfg:
            raise UsageError(f"--init {init}: its architecture differs from --config")
        model.load_state_dict(src.state_dict(), strict=True)
    else:
        if not Path(init).exists():
            raise FileNotFoundError(f"--init {init} does not exist")
        load_glc_checkpoint(model, init)


def _build_model(cfg: GLCStoreTrainConfig) -> GLC:
    """The GLC to train: seeded random initialisation, or `cfg.init`'s weights, on `cfg.device`."""
    torch.manual_seed(cfg.optim.seed)
    model = GLC(CONFIGS[cfg.config]())
    if cfg.init:
        _load_init(model, cfg.init)
    return model.to(cfg.device)


def _param_text(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple | list):
        return json.dumps([str(v) if isinstance(v, Path) else v for v in value])
    return str(value)


def source_params_text(params: GazeSourceParams) -> tuple[str, ...]:
    """The fields of `params` that differ from their defaults as command-line `key=value` text (what
    `gazereg.gaze.sources.parse_source_params` reads back: `gazereg glc eval` rebuilds the source from it)."""
    default = type(params)()
    return tuple(
        f"{f.name}={_param_text(getattr(params, f.name))}"
        for f in dataclasses.fields(params)
        if getattr(params, f.name) != getattr(default, f.name)
    )


def _run_settings(cfg: GLCStoreTrainConfig, split: HoldoutSplit, ds: StoreClipDataset) -> dict[str, Any]:
    """What run.json records (and glc_train.json repeats)."""
    _, gaze_valid = ds.gaze()
    return {
        "command": to_dict(cfg),
        "split": split.to_dict(),
        "camera": cfg.camera,
        "gaze_source": cfg.gaze.name,
        "gaze_params": list(source_params_text(cfg.gaze)),
        "stride": cfg.stride,
        "train_clips": len(ds),
        "train_frames_with_gaze": int(gaze_valid.sum()),
    }


def task_split(store: EpisodeStore, cfg: GLCRunSettings) -> HoldoutSplit:
    """The episodes to train on and to evaluate on: `holdout_split` within `cfg.tasks` (all tasks when
    empty), or with `cfg.heldout_tasks` every episode of `cfg.tasks` to train on and every holdout_every-th
    episode of each held-out task (ranks 0, holdout_every, ...) to evaluate on. UsageError for a task the
    store lacks."""
    by_task: dict[str, list[int]] = {}
    for i in store.indices():
        by_task.setdefault(store.meta(i)["task"], []).append(i)
    missing = [t for t in (*cfg.tasks, *cfg.heldout_tasks) if t not in by_task]
    if missing:
        raise UsageError(
            f"--tasks / --heldout-tasks: {store.root} has no episodes of {missing}; its tasks: {sorted(by_task)}"
        )
    if cfg.heldout_tasks:
        train = sorted(i for t in cfg.tasks for i in by_task[t])
        held = sorted(i for t in cfg.heldout_tasks for i in by_task[t][:: cfg.holdout_every])
        return HoldoutSplit(tuple(train), tuple(held))
    split = holdout_split(store, cfg.holdout_every, cfg.holdout)
    if not cfg.tasks:
        return split
    keep = {i for t in cfg.tasks for i in by_task[t]}
    return HoldoutSplit(
        tuple(i for i in split.train if i in keep), tuple(i for i in split.heldout if i in keep)
    )


def _evaluate(
    cfg: GLCStoreTrainConfig, store: EpisodeStore, split: HoldoutSplit, final: Path, source: Any
) -> tuple[Path, dict[str, Any]]:
    """Evaluate the model in `final` on the held-out episodes; writes and returns `<out>/eval.json`."""
    model = GLCParams(checkpoint=final, stride=cfg.stride, device=cfg.device)
    report = evaluate_glc(store, model, split.heldout, split.train, cfg.camera, source)
    path = Path(cfg.out) / "eval.json"
    atomic_write_json(path, report)
    return path, report


def train_glc_on_store(cfg: GLCStoreTrainConfig) -> GLCStoreTrainResult:
    """Train (or resume training) a GLC on `cfg.store`'s gaze and evaluate it; files in the module docstring."""
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    store = EpisodeStore(cfg.store)
    sweep_stale_temps(cfg.out)  # what killed writers of an earlier attempt left
    split = task_split(store, cfg)
    if not split.train:
        raise UsageError(
            f"--holdout / --holdout-every / --tasks: no training episodes left in {cfg.store} after holding out "
            f"{indices_text(split.heldout)}"
        )
    model = _build_model(cfg)
    source = gaze_points_source(cfg.gaze, store)
    t0 = time.perf_counter()
    mc = model.cfg
    ds = StoreClipDataset(
        store, split.train, cfg.camera, mc.crop_size, mc.num_frames, cfg.stride, cfg.clip_hop, source
    )
    log.info(
        "glc train: %d clips from %d episodes (%.1f s to load), held out: %s",
        len(ds),
        len(split.train),
        time.perf_counter() - t0,
        indices_text(split.heldout),
    )
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    settings = _run_settings(cfg, split, ds)
    atomic_write_json(out / "run.json", settings)
    t1 = time.perf_counter()
    trained = train_glc(model, ds, cfg.optim, out, resume=cfg.resume)
    train_s = time.perf_counter() - t1
    final = save_glc(model, model.cfg, out / "final")
    losses = [v for _, v in trained.losses]
    first, last10 = (losses[0], float(np.mean(losses[-10:]))) if losses else (None, None)
    info = {**settings, "steps": trained.step, "train_seconds_this_run": round(train_s, 1)}
    atomic_write_json(final / "glc_train.json", {**info, "first_loss": first, "last_loss_mean10": last10})
    log.info(
        "GLC (%s) trained to step %d in %.0f s; model written to %s", cfg.config, trained.step, train_s, final
    )
    result = GLCStoreTrainResult(final, trained.step, split, train_s, first, last10)
    if cfg.evaluate and split.heldout:
        eval_path, report = _evaluate(cfg, store, split, final, source)
        result = replace(result, eval_path=eval_path, eval_report=report)
    return result
