"""The experiment's demonstrations: which collections it runs (and on which setups), and what they gave.

    configs = demo_collections(cfg, out)     # {"train": CollectConfig, "heldout": ..., ["glc": ...]}
    collect_seeds(configs["train"])          # the setups the training demonstrations may come from

Only the tasks with demonstrations are collected (`ExperimentConfig.demo_tasks`: not `tasks_without_demos`).
The training demonstrations are on setups 0.. (`demos_per_task`, plus `demo_max_failures` replacements for the
expert's failures), the held-out ones (attention-gaze alignment only, never trained on) and the GLC's own
(single-GLC runs only) on setups counted from the evaluation's first setup seed plus an offset of their own.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from gazereg.data.store import EpisodeStore
from gazereg.envs.collect import CollectReport
from gazereg.envs.collect_config import CollectConfig
from gazereg.experiment.arms import trains_glc
from gazereg.experiment.config import ExperimentConfig

HELDOUT_OFFSET = 500
"""the held-out demonstrations' first setup seed, counted from the evaluation's first"""
GLC_OFFSET = 700
"""the GLC demonstrations' first setup seed, counted from the evaluation's first"""


def demo_stores(out: Path) -> dict[str, Path]:
    """Each collection's episode store under the run folder `out`."""
    return {"train": out / "demos", "heldout": out / "heldout", "glc": out / "glc_demos"}


def demo_collections(cfg: ExperimentConfig, out: Path) -> dict[str, CollectConfig]:
    """Every collection the demos stage runs, by name: the training demonstrations, the held-out ones and,
    when the experiment trains one GLC on demonstrations of its own, the GLC's."""
    stores = demo_stores(out)
    common: dict[str, Any] = dict(
        env=cfg.env,
        tasks=cfg.demo_tasks,
        cameras=(cfg.camera,),
        image_size=cfg.image_size,
        max_steps=cfg.demo_max_steps,
        workers=cfg.collect_workers,
        gl_backend=cfg.eval.gl_backend or "",
    )
    start = cfg.eval.seed_start
    sets = {
        "train": CollectConfig(
            out=stores["train"],
            episodes=cfg.demos_per_task,
            max_failures=cfg.demo_max_failures,
            seed_base=0,
            **common,
        ),
        "heldout": CollectConfig(
            out=stores["heldout"],
            episodes=cfg.heldout_per_task,
            seed_base=start + HELDOUT_OFFSET if cfg.heldout_seed_start is None else cfg.heldout_seed_start,
            **common,
        ),
    }
    if trains_glc(cfg) and not cfg.glc_folds:
        sets["glc"] = CollectConfig(
            out=stores["glc"], episodes=cfg.glc_demos_per_task, seed_base=start + GLC_OFFSET, **common
        )
    return sets


def task_instructions(metas: Iterable[Mapping[str, Any]]) -> dict[str, str]:
    """{task: its instruction} of episodes' metadata (`EpisodeStore.meta`), sorted by task (the first
    episode's, when a task's episodes differ). The task is the one the collection ran and the evaluation names
    (`env_name`, e.g. `libero_spatial/4`), not the simulator's own name for it (`task`, e.g. LIBERO's
    `pick_up_the_black_bowl_...`), which only episodes recorded without `env_name` fall back on."""
    out: dict[str, str] = {}
    for meta in metas:
        out.setdefault(str(meta.get("env_name", meta["task"])), str(meta.get("instruction", "")))
    return dict(sorted(out.items()))


def collection_result(
    name: str, report: CollectReport, store: EpisodeStore, without: Mapping[str, str] | None = None
) -> dict[str, Any]:
    """What the demos stage records of one collection: episodes and frames in its store (one read of each
    episode's metadata), seconds and, for the training demonstrations, the episodes wanted and kept per task
    (0 for the tasks `without` demonstrations, {task: instruction}, which it also lists) and each task's
    instruction (`task_instructions`, and those of the tasks without). RuntimeError when a collection
    other than the training one is incomplete, or when some task has no training demonstration at all
    (fewer than wanted is accepted there: the expert failed on some of the allowed setups)."""
    per_task = {task: r["episodes"] for task, r in report.tasks.items()}
    metas = [store.meta(i) for i in store.indices()]
    frames = sum(int(m["length"]) for m in metas)
    out: dict[str, Any] = {"episodes": len(metas), "frames": frames, "seconds": report.seconds}
    if name != "train":
        if not report.complete:
            raise RuntimeError(
                f"{name} demonstrations: some task has fewer successful episodes than wanted: {per_task}"
            )
        return out
    empty = [task for task, n in per_task.items() if n == 0]
    if empty:
        raise RuntimeError(
            f"no training demonstration of {empty}: the expert failed on every allowed setup "
            f"({report.tasks[empty[0]]['failed_seeds']}); raise --demo-max-failures"
        )
    wanted = next(iter(report.tasks.values()))["wanted"]
    without = without or {}
    return {
        **out,
        "wanted": wanted,
        "per_task": {**per_task, **{task: 0 for task in without}},
        "without": list(without),
        "instructions": dict(sorted({**task_instructions(metas), **without}.items())),
    }
