"""Multi-process training: `accelerate launch --multi_gpu --num_processes 2 lerobot-train --policy.type=smolvla_gaze`
on two CPU processes (Gloo) gives the gaze term, and the values lerobot-train logs for it, of one process on the
same global batch.

Why the gaze term needs care: it is a mean over the frames WITH gaze. Two processes holding different numbers of
such frames would each take their own mean, and DDP (gradients) and lerobot-train (`MetricsTracker.
reduce_across_ranks`, logs) average those means: frames on the process with fewer valid frames would weigh more.
The plugin rescales each process's mean to its share of the global mean (`gaze_common.across_processes`).

The runs here: episode 0 of the tiny fixture (20 frames: the whole episode is one global batch, 20 frames in one
process or 10 + 10 in two) with gaze removed from 3 frames (an odd number: the two processes never hold the
same number of valid frames). lerobot's flow matching draws noise and times per process, so a test-only
sitecustomize gives every frame the same noise and time in both runs (lerobot's per-frame computation is then a
function of the frame alone) and records each process's loss dict at full precision (lerobot-train prints 3
decimals).

Tolerance: 1e-5 relative on the full-precision values. The per-frame float32 divergences are summed in another
order (10 + 10, rescaled, then averaged over the processes, vs one sum of 20) after matmuls over 10-row instead of
20-row batches; the measured differences are about 3e-7 relative. Without the rescaling the first step logs
1.980 instead of 1.969. The printed logs are compared within 1.5e-3 (3 decimals each, rounded independently).
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from conftest import tiny_smolvla_gaze_flags

INVALID = (0, 1, 2)  # frames of episode 0 whose gaze point becomes NaN (no gaze)
SITE = textwrap.dedent(
    """
    import json, os, sys
    if os.path.basename(sys.argv[0]).startswith("lerobot-train"):
        import torch
        from lerobot.policies.smolvla import modeling_smolvla as m
        from lerobot_policy_gazereg.modeling_smolvla_gaze import SmolVLAGazePolicy

        def sample_noise(self, shape, device):  # the same noise for every frame, in every process
            g = torch.Generator().manual_seed(7)
            return torch.randn(tuple(shape[1:]), generator=g).expand(tuple(shape)).to(device)

        def sample_time(self, bsize, device):
            return torch.full((bsize,), 0.5, device=device)

        m.VLAFlowMatching.sample_noise, m.VLAFlowMatching.sample_time = sample_noise, sample_time
        orig = SmolVLAGazePolicy.forward

        def forward(self, batch, *args, **kwargs):
            loss, out = orig(self, batch, *args, **kwargs)
            if self.training:
                rank = int(os.environ.get("RANK", "0"))
                rec = {"index": batch["index"].tolist(), **{k: v for k, v in out.items() if type(v) is float}}
                with open(os.path.join(os.environ["GAZEREG_TEST_RECORDS"], f"rank{rank}.jsonl"), "a") as f:
                    f.write(json.dumps(rec) + "\\n")
            return loss, out

        SmolVLAGazePolicy.forward = forward
    """
)


@pytest.fixture(scope="module")
def gaps_dataset(tmp_path_factory, dataset_root) -> Path:
    """The fixture with no gaze on frames INVALID (a copy: the gaze column's values only)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    root = tmp_path_factory.mktemp("gaps") / "lerobot_v3_tiny"
    shutil.copytree(dataset_root, root)
    (f,) = (root / "data").rglob("*.parquet")
    table = pq.read_table(f)
    field = table.schema.field("gaze.point")
    values = [
        [math.nan, math.nan] if i in INVALID else v
        for i, v in zip(
            table.column("index").to_pylist(), table.column("gaze.point").to_pylist(), strict=True
        )
    ]
    table = table.set_column(table.schema.get_field_index("gaze.point"), field, pa.array(values, field.type))
    pq.write_table(table, f)
    return root


def _train(tmp_path: Path, tiny_vlm: Path, dataset: Path, processes: int) -> tuple[str, list[list[dict]]]:
    """(log, records per process) of a 2-step lerobot-train run on episode 0 (a global batch of 20 frames)."""
    out = tmp_path / f"p{processes}"
    records = out / "records"
    records.mkdir(parents=True)
    site = out / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(SITE)
    bin_dir = Path(sys.executable).parent
    cmd = [str(bin_dir / "lerobot-train")]
    if processes > 1:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        cmd = [str(bin_dir / "accelerate"), "launch", "--multi_gpu", "--num_processes", str(processes)]
        cmd += ["--num_machines", "1", "--mixed_precision", "no", "--dynamo_backend", "no"]
        cmd += ["--main_process_port", str(port), str(bin_dir / "lerobot-train")]
    cmd += [
        *tiny_smolvla_gaze_flags(tiny_vlm),
        "--policy.gaze_weight=1.0",
        "--policy.gaze_camera=observation.images.front",
        "--policy.gaze_layers=[1,3]",
        "--policy.scheduler_warmup_steps=0",
        "--dataset.repo_id=local/lerobot_v3_tiny",
        f"--dataset.root={dataset}",
        "--dataset.episodes=[0]",
        "--dataset.video_backend=pyav",
        f"--batch_size={20 // processes}",
        "--steps=2",
        "--log_freq=1",
        "--save_freq=2",
        "--num_workers=0",
        "--wandb.enable=false",
        f"--output_dir={out / 'run'}",
    ]
    path = os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "OMP_NUM_THREADS": "1",
           "PYTHONPATH": path, "GAZEREG_TEST_RECORDS": str(records)}  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env, cwd=tmp_path)
    log = r.stdout + r.stderr
    assert r.returncode == 0, log[-4000:]
    recs = [
        [json.loads(line) for line in (records / f"rank{k}.jsonl").read_text().splitlines()]
        for k in range(processes)
    ]
    return log, recs


def _logged(log: str, step: int) -> dict[str, float]:
    (line,) = [x for x in log.splitlines() if re.search(rf"\bstep:{step} ", x)]
    return {k: float(v) for k, v in re.findall(r"((?:loss|gaze)/[a-z_]+):([-0-9.naif]+)", line)}


def test_two_processes_give_the_gaze_term_of_one(tmp_path, tiny_vlm, gaps_dataset):
    log1, (one,) = _train(tmp_path, tiny_vlm, gaps_dataset, 1)
    log2, (r0, r1) = _train(tmp_path, tiny_vlm, gaps_dataset, 2)
    assert "Effective batch size: 10 x 2 = 20" in log2 and "Effective batch size: 20 x 1 = 20" in log1
    # the same global batch: the two processes' frames are the one process's
    first = [one[0], r0[0], r1[0]]
    assert sorted(first[0]["index"]) == sorted(first[1]["index"] + first[2]["index"]) == list(range(20))
    counts = [sum(i not in INVALID for i in rec["index"]) for rec in first[1:]]
    assert counts[0] != counts[1] and sum(counts) == 17  # the premise: the processes hold different counts
    # full precision: lerobot-train's log is the mean over the processes
    for key in ("loss/gaze_kl", "gaze/valid_frac", "gaze/patch_mass"):
        mean = (first[1][key] + first[2][key]) / 2
        assert mean == pytest.approx(first[0][key], rel=1e-5), (key, first)
    assert first[0]["gaze/valid_frac"] == pytest.approx(17 / 20)
    # the printed logs of the first step
    a, b = _logged(log1, 1), _logged(log2, 1)
    for key in ("loss/gaze_kl", "gaze/valid_frac", "gaze/patch_mass", "gaze/weight"):
        assert abs(a[key] - b[key]) <= 1.5e-3, (key, a, b)


# ----- the rescaling itself, with gradients: two Gloo processes vs one ----------------------------------------
def _worker(rank: int, world: int, port: int, out: str) -> None:
    from lerobot_policy_gazereg.gaze_common import across_processes

    from gazereg.losses import gaze_loss

    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    torch.distributed.init_process_group("gloo", rank=rank, world_size=world)
    try:
        theta, x, gaze, valid = _problem()
        theta.requires_grad_(True)
        rows = slice(rank * 4, rank * 4 + 4)
        kl, _ = gaze_loss(gaze[rows], torch.softmax(theta + x[rows], -1), valid[rows])
        kl = across_processes(kl, valid[rows])
        kl.backward()
        grad = theta.grad.clone()
        torch.distributed.all_reduce(grad)  # what DDP does: the mean of the processes' gradients
        value = kl.detach().reshape(1).clone()
        torch.distributed.all_reduce(value)
        if rank == 0:
            torch.save({"value": value / world, "grad": grad / world}, out)
    finally:
        torch.distributed.destroy_process_group()


def _problem():
    """(theta (16,), per-frame logits x (8, 16), gaze (8, 16), valid (8,)): 4 frames per process, 3 valid on
    process 0 and 1 on process 1."""
    g = torch.Generator().manual_seed(0)
    theta = torch.randn(16, generator=g)
    x = torch.randn(8, 16, generator=g)
    gaze = torch.softmax(torch.randn(8, 16, generator=g) * 2, -1)
    valid = torch.tensor([True, True, True, False, True, False, False, False])
    return theta, x, gaze, valid


def test_across_processes_gives_the_global_mean_and_its_gradient(tmp_path):
    from gazereg.losses import gaze_loss

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = tmp_path / "two.pt"
    torch.multiprocessing.spawn(_worker, args=(2, port, str(out)), nprocs=2, join=True)
    two = torch.load(out)
    theta, x, gaze, valid = _problem()
    theta.requires_grad_(True)
    kl, _ = gaze_loss(gaze, torch.softmax(theta + x, -1), valid)
    kl.backward()
    # float32 sums in another order: 1e-6 relative (a per-process mean would be off by about 10 %)
    torch.testing.assert_close(two["value"][0], kl.detach(), rtol=1e-6, atol=0)
    torch.testing.assert_close(two["grad"], theta.grad, rtol=1e-5, atol=1e-7)
