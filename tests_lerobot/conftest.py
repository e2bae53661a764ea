"""Shared fixtures of the LeRobot lane (Python 3.12 venv with lerobot 0.6.1 and the gazereg plugin)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

pytest.importorskip("lerobot", reason="the LeRobot lane needs lerobot (scripts/lerobot_lane.sh)")
pytest.importorskip("lerobot_policy_gazereg", reason="the gazereg LeRobot plugin is not installed")

FIXTURE = Path(os.environ.get("GAZEREG_FIXTURES", "/work/shared/fixtures")) / "lerobot_v3_tiny"


@pytest.fixture(scope="session")
def dataset_root() -> Path:
    if not (FIXTURE / "meta" / "info.json").exists():
        pytest.skip(f"the LeRobot v3 fixture is missing at {FIXTURE}")
    return FIXTURE


@pytest.fixture(scope="session")
def tiny_vlm(tmp_path_factory) -> Path:
    from lerobot_policy_gazereg.testing import make_tiny_smolvlm

    return make_tiny_smolvlm(tmp_path_factory.mktemp("tiny_smolvlm"))


@pytest.fixture(scope="session")
def dataset(dataset_root):
    from lerobot.datasets import LeRobotDataset

    return LeRobotDataset(
        "local/lerobot_v3_tiny",
        root=dataset_root,
        delta_timestamps={"action": [i / 10 for i in range(5)]},
        video_backend="pyav",
    )


def tiny_smolvla_gaze_flags(tiny_vlm: Path) -> list[str]:
    """The `lerobot-train` options of a tiny smolvla_gaze on the CPU (a 4-layer VLM built from `tiny_vlm`'s
    config, no weights loaded, 64 px images, chunks of 5): what every lane test that trains one starts from."""
    return [
        "--policy.type=smolvla_gaze",
        f"--policy.vlm_model_name={tiny_vlm}",
        "--policy.load_vlm_weights=false",
        "--policy.resize_imgs_with_padding=[64,64]",
        "--policy.chunk_size=5",
        "--policy.n_action_steps=5",
        "--policy.num_vlm_layers=4",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
    ]


def make_config(tiny_vlm, **kw):
    from lerobot_policy_gazereg.configuration_smolvla_gaze import SmolVLAGazeConfig
    from lerobot_policy_gazereg.testing import tiny_smolvla_args

    args = {
        **tiny_smolvla_args(tiny_vlm),
        "gaze_weight": 1.0,
        "gaze_camera": "observation.images.front",
        **kw,
    }
    return SmolVLAGazeConfig(**args)


@pytest.fixture
def policy_and_batch(tiny_vlm, dataset):
    import torch
    from lerobot.policies import make_policy, make_pre_post_processors

    torch.manual_seed(0)
    cfg = make_config(tiny_vlm)
    policy = make_policy(cfg, ds_meta=dataset.meta)
    pre, _ = make_pre_post_processors(cfg, dataset_stats=dataset.meta.stats)
    raw = torch.utils.data.default_collate([dataset[i] for i in range(4)])
    return policy, pre(raw), raw
