"""Training-step cost of the LeRobot plugin's gaze term (`smolvla_gaze`) against plain `smolvla` (CPU), as JSON.

    ~/.cache/gazereg/lerobot-py312/bin/python benchmarks/bench_lerobot_capture.py [--steps 15] [--batch 4]

Needs the LeRobot lane (Python >= 3.12 venv with lerobot 0.6.1 and the plugin, scripts/lerobot_lane.sh); under
another interpreter without lerobot it prints {"skipped": ...} and exits 0, so benchmarks/run_all.py keeps going.

Builds the tiny offline SmolVLA of tests_lerobot/ twice from the same seed (a local SmolVLM config with random
weights, `load_vlm_weights=False`): plain `smolvla` and `smolvla_gaze` with gaze_weight 0.1 (attention capture +
KL), on one batch of the LeRobot v3 fixture. Each step is forward + backward (grads cleared before) with the
same noise and flow time for both modes; modes are interleaved (order alternating per step) after warm-up
steps, and the median per-step time of each is reported. One CPU thread.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from _timing import machine_info

DEFAULT_FIXTURE = Path(os.environ.get("GAZEREG_FIXTURES", "/work/shared/fixtures")) / "lerobot_v3_tiny"
GAZE_CAMERA = "observation.images.front"


def build(kind: str, vlm: Path, dataset, seed: int):
    """(policy, pre-processed batch source) for `smolvla` or `smolvla_gaze`, as tests_lerobot/conftest.py does."""
    import torch
    from lerobot.policies import make_policy, make_pre_post_processors
    from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig
    from lerobot_policy_gazereg.configuration_smolvla_gaze import SmolVLAGazeConfig
    from lerobot_policy_gazereg.testing import tiny_smolvla_args

    args = tiny_smolvla_args(vlm)
    if kind == "gaze":
        cfg = SmolVLAGazeConfig(**args, gaze_weight=0.1, gaze_camera=GAZE_CAMERA)
    else:
        cfg = SmolVLAConfig(**args)
    torch.manual_seed(seed)
    policy = make_policy(cfg, ds_meta=dataset.meta)
    pre, _ = make_pre_post_processors(cfg, dataset_stats=dataset.meta.stats)
    policy.train()
    return policy, pre


def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=15, help="timed steps per mode (interleaved)")
    ap.add_argument("--warmup", type=int, default=3, help="untimed steps per mode first")
    ap.add_argument("--batch", type=int, default=4, help="frames of the fixture in the batch")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fixture", type=Path, default=DEFAULT_FIXTURE)
    return ap.parse_args()


def interleaved_steps(modes: dict, noise: Any, flow_t: Any, steps: int, warmup: int) -> tuple[dict, dict]:
    """({mode: seconds per forward + backward}, {mode: the last step's info}) over `steps` rounds that
    alternate the modes' order, after `warmup` untimed rounds; `modes` maps a name to (policy, batch)."""

    def step(mode: str) -> tuple[float, dict]:
        policy, batch = modes[mode]
        policy.zero_grad(set_to_none=True)
        t0 = time.perf_counter()
        loss, info = policy.forward(dict(batch), noise=noise, time=flow_t)
        loss.backward()
        return time.perf_counter() - t0, info

    for _ in range(warmup):
        for mode in modes:
            step(mode)
    times: dict[str, list[float]] = {m: [] for m in modes}
    infos: dict[str, dict] = {}
    for i in range(steps):
        for mode in ("plain", "gaze") if i % 2 == 0 else ("gaze", "plain"):
            dt, infos[mode] = step(mode)
            times[mode].append(dt)
    return times, infos


def main() -> int:
    a = parse_args()
    try:
        import lerobot
    except ImportError:
        print(json.dumps({"skipped": "needs lerobot (Python >= 3.12 lane)"}))
        return 0
    if not (a.fixture / "meta" / "info.json").exists():
        print(json.dumps({"skipped": f"the LeRobot v3 fixture is missing at {a.fixture}"}))
        return 0
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("HF_DATASETS_OFFLINE", "1")

    import torch
    from lerobot.datasets import LeRobotDataset
    from lerobot_policy_gazereg.testing import make_tiny_smolvlm

    torch.set_num_threads(a.threads)
    dataset = LeRobotDataset(
        "local/lerobot_v3_tiny",
        root=a.fixture,
        delta_timestamps={"action": [i / 10 for i in range(5)]},
        video_backend="pyav",
    )
    raw = torch.utils.data.default_collate([dataset[i] for i in range(a.batch)])
    with tempfile.TemporaryDirectory() as tmp:
        vlm = make_tiny_smolvlm(Path(tmp) / "tiny_smolvlm")
        plain, pre_plain = build("plain", vlm, dataset, a.seed)
        gaze, pre_gaze = build("gaze", vlm, dataset, a.seed)
    same_init = all(
        torch.equal(p, q)
        for p, q in zip(plain.state_dict().values(), gaze.state_dict().values(), strict=True)
    )
    modes = {"plain": (plain, pre_plain(dict(raw))), "gaze": (gaze, pre_gaze(dict(raw)))}
    g = torch.Generator().manual_seed(a.seed + 1)
    noise = torch.randn(a.batch, plain.config.chunk_size, plain.config.max_action_dim, generator=g)
    times, infos = interleaved_steps(modes, noise, torch.full((a.batch,), 0.5), a.steps, a.warmup)

    plain_s, gaze_s = statistics.median(times["plain"]), statistics.median(times["gaze"])
    out = {
        "step_s_plain": round(plain_s, 5),
        "step_s_gaze": round(gaze_s, 5),
        "ratio": round(gaze_s / plain_s, 4),
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "lerobot": getattr(lerobot, "__version__", None) or _dist_version("lerobot"),
        "steps": a.steps,
        "warmup": a.warmup,
        "batch": a.batch,
        "same_init": same_init,
        "gaze_kl": round(float(infos["gaze"]["loss/gaze_kl"]), 5),
        "step_s_plain_all": [round(t, 5) for t in times["plain"]],
        "step_s_gaze_all": [round(t, 5) for t in times["gaze"]],
        "python": platform.python_version(),
        "machine": machine_info(precision="no", node=platform.node()),  # float32 training steps
    }
    print(json.dumps(out))
    return 0


def _dist_version(name: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return None


if __name__ == "__main__":
    sys.exit(main())
