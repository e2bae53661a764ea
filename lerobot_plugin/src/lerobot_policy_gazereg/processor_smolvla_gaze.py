"""Pre/post-processors of `smolvla_gaze`: SmolVLA's own pipelines, with a batch converter that keeps the gaze
column. LeRobot's default `batch_to_transition` keeps only observation.*, action, *_is_pad and a fixed set of
metadata keys; here gaze.* keys ride along as complementary data and `transition_to_batch` puts them back.
"""

from __future__ import annotations

from typing import Any

from lerobot.lerobot_types import TransitionKey
from lerobot.policies.smolvla.processor_smolvla import make_smolvla_pre_post_processors
from lerobot.processor.converters import batch_to_transition

from .configuration_smolvla_gaze import SmolVLAGazeConfig

GAZE_PREFIX = "gaze."


def batch_to_transition_keep_gaze(batch: dict[str, Any]):
    transition = batch_to_transition(batch)
    gaze = {k: v for k, v in batch.items() if k.startswith(GAZE_PREFIX)}
    if gaze:
        comp = dict(transition.get(TransitionKey.COMPLEMENTARY_DATA) or {})
        comp.update(gaze)
        transition[TransitionKey.COMPLEMENTARY_DATA] = comp
    return transition


def make_smolvla_gaze_pre_post_processors(config: SmolVLAGazeConfig, dataset_stats=None):
    pre, post = make_smolvla_pre_post_processors(config, dataset_stats=dataset_stats)
    pre.to_transition = batch_to_transition_keep_gaze
    return pre, post
