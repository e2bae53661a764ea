"""What an experiment writes about itself: its saved configuration, read back to resume, and the report's spec.

check_same_config(as_saved_now(saved, folder, cfg), cfg, ...)   # folder's config.json against cfg
as_trained(saved, folder)     # "auto" precision as the folder's runs recorded training in
report_spec(cfg, "quick")     # what report.md says the experiment ran
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from gazereg.experiment.config import ExperimentConfig
from gazereg.experiment.finished import recorded_precision
from gazereg.report.build import ReportSpec
from gazereg.runtime.config import to_dict
from gazereg.training.arms import arm


def with_added_keys(saved: dict[str, Any], default: dict[str, Any], new: dict[str, Any]) -> dict[str, Any]:
    """A saved config.json (`to_dict`) completed with the keys added to the configuration since it was saved:
    each key that `new` (the config now given) has and `saved` lacks takes its value in `default` (the
    class's default config), the behaviour the run had before the key existed. A run folder made before a
    key existed thus resumes when the key keeps its default, and is refused (naming it) when it does not."""
    out = dict(saved)
    for key, value in new.items():
        if key not in default:
            continue
        if key not in out:
            out[key] = default[key]
        elif isinstance(value, dict) and isinstance(out[key], dict) and isinstance(default[key], dict):
            out[key] = with_added_keys(out[key], default[key], value)
    return out


def as_trained(saved: dict[str, Any], folder: str | Path) -> dict[str, Any]:
    """The experiment `folder`'s saved config.json (`saved`) with a training precision saved as "auto" replaced
    by the one every run of the folder recorded training in (`finished.recorded_precision`): "auto" is bf16 on
    a CPU with native bf16 and float32 elsewhere, so what a run trained in is the record, not the flag. Kept
    "auto" when the folder records no single precision."""
    train = saved.get("train")
    if not (isinstance(train, dict) and train.get("mixed_precision") == "auto"):
        return saved
    recorded = recorded_precision(folder)
    return saved if recorded is None else {**saved, "train": {**train, "mixed_precision": recorded}}


def as_saved_now(saved: dict[str, Any], folder: str | Path, cfg: ExperimentConfig) -> dict[str, Any]:
    """The experiment `folder`'s saved config.json (`saved`) as `cfg` would save the same experiment: keys
    added since completed (`with_added_keys`), and a training precision saved as "auto" counted as the one
    every run of the folder recorded training in (`as_trained`) when `cfg` names that precision. Pinning a
    preset's precision (a study run in sittings on machines whose "auto" differs) keeps the sittings that
    trained in that precision under "auto" its own; one that trained in another, or did not record it, still
    differs."""
    out = with_added_keys(saved, to_dict(ExperimentConfig()), to_dict(cfg))
    pinned = cfg.train.mixed_precision
    if pinned == "auto":
        return out
    trained = as_trained(out, folder)
    return trained if trained.get("train", {}).get("mixed_precision") == pinned else out


def report_spec(cfg: ExperimentConfig, preset: str) -> ReportSpec:
    """What the report says the experiment ran."""
    return ReportSpec(
        preset=preset,
        tasks=cfg.tasks,
        arms=cfg.arms,
        train_seeds=cfg.train_seeds,
        train_steps=cfg.train.steps,
        batch_size=cfg.train.batch_size,
        gaze_weight=cfg.train.gaze.weight,
        gaze_layers=tuple(cfg.train.gaze.layers),
        gaze_queries=cfg.train.gaze.queries,
        gaze_arms=tuple(a for a in cfg.arms if arm(a).prior(cfg, None) is not None),
        eval_episodes=cfg.eval.episodes,
        eval_conditions=tuple(cfg.eval.conditions),
        eval_seed_start=cfg.eval.seed_start,
        eval_robustness_episodes=cfg.eval.robustness_episodes,
        convergence_episodes=cfg.convergence_episodes,
        threshold=cfg.threshold,
        config=to_dict(cfg),
    )
