"""The GLC the experiment trains for the glc arm (priors stage): one on GLC demonstrations of its own, or one per
fold of `ExperimentConfig.glc_folds` on the other folds' training demonstrations (cross-fitted).

    train_glc(cfg, glc_store)              # {"checkpoint", "steps", "eval"}
    train_glc_folds(cfg, store, names)     # {"folds": [{"predicts", "trained_on", "checkpoint", "steps", "eval"}]}

Training resumes from the newest checkpoint. "eval" holds the GLC's F1 and AUC (`gazereg.gaze.glc.evaluate`)
on held-out episodes next to a centre prior fitted on its training episodes' gaze and the uniform map: for
one GLC every 5th GLC demonstration per task, for a fold GLC every 5th training demonstration of each task
it predicts (tasks it never trained on).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from gazereg.experiment.arms import fold_tasks, glc_dir, glc_fold_dir
from gazereg.experiment.config import ExperimentConfig
from gazereg.training.glc_store import GLCStoreTrainConfig, GLCStoreTrainResult, train_glc_on_store

SCORED = ("glc", "centre_prior", "uniform")
"""the maps scored against the gaze: the GLC's, a centre prior fitted on its training gaze, uniform"""


def _run(cfg: ExperimentConfig, store: Path, out: Path, **changes: Any) -> GLCStoreTrainResult:
    """Train (or resume) one GLC on the gaze source's points of `store`'s episodes into `out`."""
    base = GLCStoreTrainConfig()
    return train_glc_on_store(
        replace(
            base,
            store=store,
            camera=cfg.camera,
            gaze=cfg.gaze,
            out=out,
            optim=replace(base.optim, steps=cfg.glc_steps),
            **changes,
        )
    )


def _record(trained: GLCStoreTrainResult) -> dict[str, Any]:
    """What the priors stage records of a trained GLC: its checkpoint, steps and held-out scores (or None)."""
    out: dict[str, Any] = {"checkpoint": str(trained.final), "steps": trained.steps, "eval": None}
    if trained.eval_path is not None:
        rep = json.loads(trained.eval_path.read_text())
        out["eval"] = {
            "heldout": rep["episodes"],
            **{
                f"{name}_{metric}": rep["scores"]["all_valid"][name][metric]
                for name in SCORED
                for metric in ("f1", "auc")
            },
        }
    return out


def train_glc(cfg: ExperimentConfig, glc_store: Path) -> dict[str, Any]:
    """The single GLC, on the GLC demonstrations (every 5th episode per task held out for its scores)."""
    return _record(_run(cfg, glc_store, glc_dir(cfg)))


def train_glc_folds(cfg: ExperimentConfig, store: Path, task_names: Mapping[str, str]) -> dict[str, Any]:
    """One GLC per fold on the training demonstrations `store` of the other folds' tasks, scored on episodes
    of the fold's own tasks; `task_names`: each task's name in the store. Tasks without demonstrations
    (`tasks_without_demos`) have no episode to train on, score or predict, so they are left out of both."""
    folds = []
    for k in range(len(cfg.glc_folds)):
        trained_on, predicts = (tuple(t for t in part if t in cfg.demo_tasks) for part in fold_tasks(cfg, k))
        trained = _run(
            cfg,
            store,
            glc_fold_dir(cfg, k),
            tasks=tuple(task_names[t] for t in trained_on),
            heldout_tasks=tuple(task_names[t] for t in predicts),
        )
        folds.append({"predicts": list(predicts), "trained_on": list(trained_on), **_record(trained)})
    return {"folds": folds, "steps": cfg.glc_steps}
