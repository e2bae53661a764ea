"""`gazereg glc eval`: evaluate the GLC video gaze estimator on an episode store.

    gazereg glc eval  --store data/demos --checkpoint runs/glc

`gazereg glc` (the table in `gazereg.cli`) dispatches `train` to `gazereg.training.glc_cli` and `eval` here.

`eval` runs the `glc` gaze source (the same code the priors use) on the held-out episodes and reports the
GLC paper's metrics (F1 / recall / precision at the best threshold, AUC) next to a centre prior fitted on
the training episodes' gaze and the uniform map; it prints a table and writes JSON.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from gazereg.data.store import EpisodeStore
from gazereg.gaze.glc.evaluate import (
    evaluate_glc,
    format_report,
    gaze_points_source,
    holdout_split,
    resolve_glc_folder,
)
from gazereg.gaze.sources import parse_source_params
from gazereg.gaze.sources.glc import CONFIGS, GLCConfigName, GLCMode, GLCParams
from gazereg.runtime.config import Validated, option, parse, require_choice, require_number
from gazereg.runtime.errors import UsageError
from gazereg.runtime.io import atomic_write_json


@dataclass(frozen=True)
class GLCEvalCommand(Validated):
    """`gazereg glc eval`'s options, checked when built (`validate`)."""

    store: Path = Path("data/demos")
    checkpoint: Path = Path("runs/glc")
    """a folder from `gazereg glc train` (run folder or its final/), or an official checkpoint file"""
    config: GLCConfigName | None = None
    """architecture of an official checkpoint file (official | small)"""
    camera: str | None = None
    """default: the training camera (glc_train.json), else corner2"""
    gaze_source: str | None = None
    """default: the training gaze source, else visuomotor"""
    gaze_params: tuple[str, ...] | None = None
    """the gaze source's parameters, key=value; default: the training run's"""
    episodes: tuple[int, ...] = ()
    """episodes to evaluate; default: the held-out episodes of training, else the holdout_every rule"""
    holdout_every: int = 5
    stride: int | None = None
    """default: the training stride, else 2"""
    mode: GLCMode = "average"
    """glc source mode: average | centre"""
    hop: int = 4
    batch_size: int = 8
    device: str = "cpu"
    threads: int = 0
    fixation_threshold: float = 0.0
    """if > 0, also score fixation frames only (gaze moved at most this much, normalised units, since the
    previous frame)"""
    centre_from: Path | None = None
    """the store whose training episodes fit the centre prior (the GLC's own training store when the
    evaluated episodes are another store's, e.g. held-out tasks); default --store"""
    out: Path | None = None
    """JSON report; default <checkpoint folder>/eval.json"""

    def validate(self, prefix: str) -> None:
        """UsageError naming the first option out of range."""
        if self.config is not None:
            require_choice(self.config, prefix + "config", sorted(CONFIGS))
        require_number(self.holdout_every, prefix + "holdout_every", 2, integer=True)
        if self.stride is not None:
            require_number(self.stride, prefix + "stride", 1, integer=True)
        for name in ("hop", "batch_size"):
            require_number(getattr(self, name), prefix + name, 1, integer=True)
        require_number(self.threads, prefix + "threads", 0, integer=True)
        require_number(self.fixation_threshold, prefix + "fixation_threshold", 0)
        for index in self.episodes:
            require_number(index, prefix + "episodes", 0, integer=True)


def _episodes(
    cfg: GLCEvalCommand, store: EpisodeStore, trained: dict[str, Any], centre: EpisodeStore
) -> tuple[list[int], list[int]]:
    """(episodes to evaluate, training episodes of `centre` for the centre prior): `--episodes`, else the
    training run's held-out ones, else the `holdout_every` rule; the training episodes are the training
    run's, else every episode not evaluated, those of `centre` (with `--centre-from`: every one the training
    run's split does not hold out)."""
    if cfg.episodes:
        episodes = sorted(set(cfg.episodes))
        missing = [i for i in episodes if i not in store]
        if missing:
            raise UsageError(f"{option('episodes')}: episodes {missing} are not in {cfg.store}")
        train = trained.get("split", {}).get("train") or [
            i for i in store.indices() if i not in set(episodes)
        ]
    elif trained.get("split"):
        episodes, train = trained["split"]["heldout"], trained["split"]["train"]
    else:
        split = holdout_split(store, cfg.holdout_every)
        episodes, train = list(split.heldout), list(split.train)
    if cfg.centre_from is not None:
        held = set(trained.get("split", {}).get("heldout", ()))
        train = trained.get("split", {}).get("train") or [i for i in centre.indices() if i not in held]
        return episodes, [i for i in train if i in centre]
    return episodes, [i for i in train if i in store and i not in set(episodes)]


def eval_command(cfg: GLCEvalCommand) -> dict[str, Any]:
    """Evaluate a GLC on held-out episodes; settings not given default to the training run's
    (`glc_train.json` next to the model); prints the table and writes the JSON report."""
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    store = EpisodeStore(cfg.store)
    centre = store
    if cfg.centre_from is not None:
        try:
            centre = EpisodeStore(cfg.centre_from)
        except FileNotFoundError as e:  # not a store: named as the option
            raise UsageError(f"{option('centre_from')}: {e}") from e
    folder = resolve_glc_folder(cfg.checkpoint)
    if folder is None and not cfg.checkpoint.exists():
        raise FileNotFoundError(f"--checkpoint {cfg.checkpoint} does not exist")
    trained: dict[str, Any] = {}
    if folder is not None and (folder / "glc_train.json").exists():
        trained = json.loads((folder / "glc_train.json").read_text())
    camera = cfg.camera or trained.get("camera", "corner2")
    gaze_name = cfg.gaze_source or trained.get("gaze_source", "visuomotor")
    gaze_params = cfg.gaze_params if cfg.gaze_params is not None else tuple(trained.get("gaze_params", ()))
    episodes, train_eps = _episodes(cfg, store, trained, centre)
    model = GLCParams(
        checkpoint=folder if folder is not None else cfg.checkpoint,
        config=cfg.config,
        stride=cfg.stride or trained.get("stride", 2),
        mode=cfg.mode,
        hop=cfg.hop,
        batch_size=cfg.batch_size,
        device=cfg.device,
    )
    params = parse_source_params(gaze_name, gaze_params)
    source = gaze_points_source(params, store)
    rep = evaluate_glc(
        store,
        model,
        episodes,
        train_eps,
        camera,
        source,
        cfg.fixation_threshold,
        centre_store=centre,
        centre_source=source if centre is store else gaze_points_source(params, centre),
    )
    rep["gaze_source"] = {"name": gaze_name, "params": list(gaze_params)}
    out = cfg.out or ((folder or cfg.checkpoint.parent) / "eval.json")
    atomic_write_json(Path(out), rep)
    print(format_report(rep))
    print(f"evaluation written to {out}")
    return rep


def eval_main(argv: list[str]) -> int:
    eval_command(parse({"default": GLCEvalCommand}, argv, prog="gazereg glc eval", description=__doc__ or ""))
    return 0
