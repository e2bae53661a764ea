"""Pre/post-processors of `pi0_gaze`: pi0's own pipelines, with the batch converter of `smolvla_gaze` that keeps
the gaze.* columns through the pre-processor."""

from __future__ import annotations

from lerobot.policies.pi0.processor_pi0 import make_pi0_pre_post_processors

from .configuration_pi0_gaze import PI0GazeConfig
from .processor_smolvla_gaze import batch_to_transition_keep_gaze


def make_pi0_gaze_pre_post_processors(config: PI0GazeConfig, dataset_stats=None):
    pre, post = make_pi0_pre_post_processors(config, dataset_stats=dataset_stats)
    pre.to_transition = batch_to_transition_keep_gaze
    return pre, post
