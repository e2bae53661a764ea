"""Pre/post-processors of `pi05_gaze`: pi05's own pipelines, with the batch converter of `smolvla_gaze` that
keeps the gaze.* columns through the pre-processor."""

from __future__ import annotations

from lerobot.policies.pi05.processor_pi05 import make_pi05_pre_post_processors

from .configuration_pi05_gaze import PI05GazeConfig
from .processor_smolvla_gaze import batch_to_transition_keep_gaze


def make_pi05_gaze_pre_post_processors(config: PI05GazeConfig, dataset_stats=None):
    pre, post = make_pi05_pre_post_processors(config, dataset_stats=dataset_stats)
    pre.to_transition = batch_to_transition_keep_gaze
    return pre, post
