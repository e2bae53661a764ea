"""What an experiment writes about itself: its saved configuration, read back to resume, and the report's spec.

check_same_config(with_added_keys(saved, to_dict(ExperimentConfig()), to_dict(cfg)), cfg, ...)
report_spec(cfg, "quick")     # what report.md says the experiment ran
"""

from __future__ import annotations

from typing import Any

from gazereg.experiment.config import ExperimentConfig
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
