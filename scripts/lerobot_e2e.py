"""The end-to-end proof through LeRobot: Meta-World demos -> LeRobot v3 data set -> gaze priors -> lerobot-train
(smolvla and smolvla_gaze) -> both checkpoints evaluated on the same unseen Meta-World setups.

    .venv/bin/python scripts/lerobot_e2e.py --out runs/lerobot_e2e                       # toy size (defaults)
    .venv/bin/python scripts/lerobot_e2e.py --out runs/e2e --tasks reach-v3 --demos 20 --steps 2000 \
        --eval-episodes 50 --gaze-source glc

Two interpreters: this one (the project venv: gazereg, Meta-World, MuJoCo) and the LeRobot lane's
(`--lane-python`, lerobot 0.6.1 + the plugin). Stages, each a subprocess:
  1. `gazereg collect`: Meta-World scripted-expert demos into an episode store (setup seeds from --demo-seed).
  2. lane: the demos written as a LeRobot v3 data set with lerobot's own `LeRobotDataset.create / add_frame /
     save_episode / finalize`, with a `gaze.point` column: the visuomotor gaze model's per-frame (u, v) trace
     (it needs the simulator's key points, which only the collected store has, so the trace is computed here
     and travels in the data set as recorded gaze).
  3. `gazereg import lerobot` -> `gazereg priors` -> `gazereg import write-gaze`: the priors as
     gaze.<camera>.heatmap / .valid in a new data set version. `--gaze-source visuomotor` (default): priors from
     the recorded trace. `--gaze-source glc` (the paper's path, no eye tracker): `gazereg glc train` on the
     visuomotor gaze of demos on setups of their own (seeds after the policy's demos), then GLC predicts every
     imported episode's gaze from its video frames alone (`priors --source glc`).
  4. lane: the real `lerobot-train`, --policy.type=smolvla and smolvla_gaze, same data, seed and steps, from
     scratch on a tiny random SmolVLM (offline, CPU).
  5. both checkpoints on the same unseen setups (seeds from --eval-seed), scripts/lerobot_e2e_eval.py.
Results: OUT/results.json, and a summary on stdout.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from lerobot_e2e_eval import attention_figure, evaluate, report_markdown

LANE_PYTHON = Path("/root/.cache/gazereg/lerobot-py312/bin/python")
REPO_ID = "local/metaworld_e2e"
MAX_FAILURES = 20  # extra demo seeds tried per task: demos use seeds demo_seed .. demo_seed + demos + 20
ROOT = Path(__file__).resolve().parents[1]
STAGE_SECONDS: dict[str, float] = {}  # this process's stages (one pipeline per process), for the report
OFFLINE = {"HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "WANDB_MODE": "disabled"}


def _run(cmd: list[str], log: Path) -> float:
    """Run `cmd`, its output into `log`; its wall time in seconds. On failure exit naming the command and the
    log's tail."""
    env = {**os.environ, **OFFLINE}
    t0 = time.time()
    with log.open("w") as f:
        r = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, env=env)
    if r.returncode != 0:
        tail = log.read_text()[-3000:]
        raise SystemExit(
            f"{tail}\nlerobot_e2e: step failed ({r.returncode}): {' '.join(cmd[:3])} ... (log: {log})"
        )
    seconds = time.time() - t0
    STAGE_SECONDS[log.stem] = round(seconds, 1)
    print(f"  {log.stem}: {seconds:.1f} s", flush=True)
    return seconds


# ----- stage 2: the demos as a LeRobot v3 data set ---------------------------------------------------------------


def export_demos(store_dir: Path, camera: str, out: Path) -> None:
    """Each stored episode to OUT/ep_NNNNNN.npz: frames uint8 (T, H, W, 3), state (T, S), action (T, A),
    gaze (T, 2) visuomotor (u, v) with NaN where invalid, instruction, fps."""
    from gazereg.data.store import EpisodeStore
    from gazereg.gaze.sources.visuomotor import VisuomotorGaze

    out.mkdir(parents=True, exist_ok=True)
    store, source = EpisodeStore(store_dir), VisuomotorGaze()
    for i in store.indices():
        ep = store.read(i, mmap=False)
        trace = source.trace(ep, camera)
        gaze = np.where(trace.valid[:, None], trace.uv, np.nan).astype(np.float32)
        np.savez(
            out / f"ep_{i:06d}.npz",
            frames=ep.frames[camera],
            state=ep.state.astype(np.float32),
            action=ep.action.astype(np.float32),
            gaze=gaze,
            instruction=np.array(ep.instruction),
            fps=np.array(float(ep.meta.get("fps", 80))),
        )


def write_lerobot(npz_dir: Path, root: Path, camera: str, vlm: Path) -> None:
    """(lane) The exported episodes as a LeRobot v3 data set at `root`, through lerobot's own writer; and the
    tiny random SmolVLM the policies train from, at `vlm` (one lane start for both)."""
    from lerobot.datasets import LeRobotDataset
    from lerobot_policy_gazereg.testing import make_tiny_smolvlm

    files = sorted(npz_dir.glob("ep_*.npz"))
    first = np.load(files[0])
    h, w = first["frames"].shape[1:3]
    features = {
        f"observation.images.{camera}": {
            "dtype": "video",
            "shape": (h, w, 3),
            "names": ["height", "width", "channels"],
        },
        "observation.state": {"dtype": "float32", "shape": first["state"].shape[1:], "names": None},
        "action": {"dtype": "float32", "shape": first["action"].shape[1:], "names": None},
        "gaze.point": {"dtype": "float32", "shape": (2,), "names": ["u", "v"]},
    }
    ds = LeRobotDataset.create(REPO_ID, fps=int(round(float(first["fps"]))), features=features, root=root)
    for f in files:
        ep = np.load(f)
        for t in range(len(ep["action"])):
            ds.add_frame(
                {
                    f"observation.images.{camera}": ep["frames"][t],
                    "observation.state": ep["state"][t],
                    "action": ep["action"][t],
                    "gaze.point": ep["gaze"][t],
                    "task": str(ep["instruction"]),
                }
            )
        ds.save_episode()
    ds.finalize()
    make_tiny_smolvlm(vlm, image_size=h)


# ----- stage 4: lerobot-train -------------------------------------------------------------------------------------


def train_args(kind: str, a: argparse.Namespace, data: Path, vlm: Path, out: Path) -> list[str]:
    """lerobot-train's command line for policy type `kind` (tiny SmolVLA from scratch, CPU)."""
    cam = f"observation.images.{a.camera}"
    args = [
        str(Path(a.lane_python).with_name("lerobot-train")),
        f"--policy.type={kind}",
        f"--policy.vlm_model_name={vlm}",
        "--policy.load_vlm_weights=false",
        f"--policy.resize_imgs_with_padding=[{a.image_size},{a.image_size}]",
        "--policy.num_vlm_layers=4",
        "--policy.chunk_size=5",
        "--policy.n_action_steps=5",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        f"--policy.optimizer_lr={a.lr}",
        "--policy.scheduler_warmup_steps=0",
        f"--dataset.repo_id={REPO_ID}",
        f"--dataset.root={data}",
        "--dataset.video_backend=pyav",
        f"--batch_size={a.batch_size}",
        f"--steps={a.steps}",
        f"--save_freq={a.steps}",
        f"--log_freq={max(1, a.steps // 20)}",
        "--num_workers=0",
        f"--seed={a.seed}",
        "--wandb.enable=false",
        f"--output_dir={out}",
    ]
    if kind == "smolvla_gaze":
        args += [
            f"--policy.gaze_key=gaze.{a.camera}.heatmap",
            f"--policy.gaze_camera={cam}",
            f"--policy.gaze_weight={a.gaze_weight}",
        ]
    return args


# ----- the pipeline -----------------------------------------------------------------------------------------------


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.RawTextHelpFormatter
    )
    p.add_argument("--out", type=Path, default=Path("runs/lerobot_e2e"), help="run folder (must not exist)")
    p.add_argument("--tasks", nargs="+", default=["reach-v3"], help="Meta-World v3 tasks")
    p.add_argument("--demos", type=int, default=2, help="expert demos per task")
    p.add_argument("--demo-seed", type=int, default=0, help="first setup seed of the demos")
    p.add_argument("--eval-episodes", type=int, default=2, help="evaluation setups per task (both arms)")
    p.add_argument("--eval-seed", type=int, default=1000, help="first unseen setup seed of the evaluation")
    p.add_argument("--eval-max-steps", type=int, default=0, help="episode length cap; 0 = Meta-World's 200")
    p.add_argument("--steps", type=int, default=2, help="lerobot-train steps per arm")
    p.add_argument("--batch-size", type=int, default=8)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--gaze-weight", type=float, default=1.0)
    p.add_argument("--seed", type=int, default=1000, help="training seed (both arms)")
    p.add_argument("--camera", default="corner2")
    p.add_argument("--image-size", type=int, default=64)
    p.add_argument("--prior-size", type=int, default=16, help="side of the written gaze heatmaps")
    p.add_argument(
        "--gaze-source",
        choices=("visuomotor", "glc"),
        default="visuomotor",
        help="the gaze arm's prior: the simulated eye trace carried in the data set, or GLC predicting it from video",
    )
    p.add_argument("--glc-demos", type=int, default=4, help="GLC's own demos per task (--gaze-source glc)")
    p.add_argument("--glc-steps", type=int, default=600, help="GLC training steps (--gaze-source glc)")
    p.add_argument(
        "--lane-python", default=str(LANE_PYTHON), help="the interpreter with lerobot 0.6.1 + plugin"
    )
    p.add_argument(
        "--results-block",
        type=Path,
        metavar="RUN",
        help="only write the docs block --marker (on the docs/*.md page holding it) from the finished run RUN",
    )
    p.add_argument("--marker", default="lerobot-e2e", help="the docs block --results-block writes")
    p.add_argument("--stage", default="all", help=argparse.SUPPRESS)  # internal: write-lerobot (lane)
    p.add_argument("--npz", type=Path, help=argparse.SUPPRESS)
    p.add_argument("--root", type=Path, help=argparse.SUPPRESS)
    p.add_argument("--vlm", type=Path, help=argparse.SUPPRESS)
    return p.parse_args(argv)


def _collect(
    gz: list[str], a: argparse.Namespace, out: Path, episodes: int, seed_base: int, log: Path
) -> None:
    """`gazereg collect`: `episodes` expert demos per task from setup seed `seed_base` on into store `out`."""
    cmd = [*gz, "collect", f"--out={out}", "--tasks", *a.tasks, f"--episodes={episodes}"]
    cmd += [f"--seed-base={seed_base}", f"--max-failures={MAX_FAILURES}", f"--cameras={a.camera}"]
    _run([*cmd, f"--image-size={a.image_size}", "--no-progress"], log)


def check_seeds(a: argparse.Namespace) -> None:
    """Exit when the demos' setup seeds (and GLC's, with --gaze-source glc) reach the evaluation seeds."""
    ranges = [("demos", a.demo_seed, a.demo_seed + a.demos + MAX_FAILURES)]
    if a.gaze_source == "glc":
        ranges.append(("GLC demos", glc_seed(a), glc_seed(a) + a.glc_demos + MAX_FAILURES))
    lo, hi = a.eval_seed, a.eval_seed + a.eval_episodes
    for name, start, stop in ranges:
        if start < hi and lo < stop:
            raise SystemExit(
                f"lerobot_e2e: evaluation seeds {lo}..{hi - 1} overlap the {name}' {start}..{stop - 1}"
            )


def glc_seed(a: argparse.Namespace) -> int:
    """First setup seed of GLC's own demos: after every seed the policy's demos may use."""
    return a.demo_seed + a.demos + MAX_FAILURES


def make_priors(gz: list[str], a: argparse.Namespace, store: Path, out: Path, logs: Path) -> dict[str, Any]:
    """The gaze prior of every imported episode, named after a.gaze_source: `recorded` (the visuomotor trace
    the data set carries as gaze.point) or `glc` (a small GLC trained here on the visuomotor gaze of demos on
    setups of their own, predicting from the data set's video frames alone). Returns GLC's held-out quality
    (None for visuomotor, or when GLC held nothing out)."""
    size, cam = [str(a.prior_size)] * 2, a.camera
    pri = [*gz, "priors", f"--store={store}", f"--camera={cam}", "--size", *size]
    if a.gaze_source == "visuomotor":
        _run([*pri, "--source=recorded"], logs / "3_priors.log")
        return {"prior": "recorded", "glc": None}
    _collect(gz, a, out / "glc_collected", a.glc_demos, glc_seed(a), logs / "3_glc_collect.log")
    glc = [*gz, "glc", "train", f"--store={out / 'glc_collected'}", f"--camera={cam}", f"--out={out / 'glc'}"]
    _run([*glc, "--gaze-source=visuomotor", f"--optim.steps={a.glc_steps}"], logs / "3_glc_train.log")
    ckpt = out / "glc" / "final"
    _run([*pri, "--source=glc", "--source-params", f"checkpoint={ckpt}"], logs / "3_priors.log")
    quality = None
    if (out / "glc" / "eval.json").exists():
        rep = json.loads((out / "glc" / "eval.json").read_text())
        scores = rep["scores"]["all_valid"]
        quality = {"heldout_episodes": len(rep["episodes"])}
        quality.update({f"{k}_{m}": scores[k][m] for k in ("glc", "centre_prior") for m in ("f1", "auc")})
    return {"prior": "glc", "glc": quality}


def pipeline(a: argparse.Namespace) -> dict[str, Any]:
    """Stages 1-5 (module doc) under a.out; returns the results."""
    gz, lane, out = [sys.executable, "-m", "gazereg.cli"], a.lane_python, a.out.resolve()
    check_seeds(a)
    if out.exists():
        raise SystemExit(f"lerobot_e2e: --out {out} exists; give a new folder")
    if not Path(lane).exists():
        raise SystemExit(f"lerobot_e2e: no LeRobot lane interpreter at {lane} (--lane-python)")
    logs = out / "logs"
    logs.mkdir(parents=True)
    t0, cam = time.time(), a.camera
    _collect(gz, a, out / "collected", a.demos, a.demo_seed, logs / "1_collect.log")
    export_demos(out / "collected", cam, out / "npz")
    data, data_gaze, vlm = out / "lerobot", out / "lerobot_gaze", out / "tiny_smolvlm"
    me = [
        lane,
        str(Path(__file__).resolve()),
        "--stage=write-lerobot",
        f"--npz={out / 'npz'}",
        f"--root={data}",
    ]
    _run([*me, f"--camera={cam}", f"--vlm={vlm}"], logs / "2_write_lerobot.log")
    store = out / "imported"
    _run(
        [*gz, "import", "lerobot", f"--root={data}", f"--out={store}", "--no-progress"], logs / "3_import.log"
    )
    prior = make_priors(gz, a, store, out, logs)
    wg = [*gz, "import", "write-gaze", f"--store={store}", f"--prior={prior['prior']}", f"--root={data}"]
    _run([*wg, f"--out={data_gaze}", "--no-progress"], logs / "3_write_gaze.log")
    arms = {}
    for kind in ("smolvla", "smolvla_gaze"):
        _run(train_args(kind, a, data_gaze, vlm, out / f"train_{kind}"), logs / f"4_train_{kind}.log")
        arms[kind] = out / f"train_{kind}" / "checkpoints" / "last" / "pretrained_model"
    results, maps = evaluate(arms, a, data_gaze, logs)
    results["attention_kl_gaze_to_attention"] = attention_figure(maps, out)
    results.update(tasks=a.tasks, demos=a.demos, steps=a.steps, gaze_source=a.gaze_source, glc=prior["glc"])
    results.update(wall_s=round(time.time() - t0, 1), stage_seconds=dict(STAGE_SECONDS), machine=machine())
    results["command"] = shlex.join(["python", "scripts/lerobot_e2e.py", *a.argv])
    (out / "results.json").write_text(json.dumps(results, indent=1))
    return results


def machine() -> str:
    """This machine in a few words: CPU model, cores, torch."""
    import platform

    import torch

    cpu = platform.processor() or platform.machine()
    for line in Path("/proc/cpuinfo").read_text().splitlines() if Path("/proc/cpuinfo").exists() else []:
        if line.startswith("model name"):
            cpu = line.split(":", 1)[1].strip()
            break
    return f"{cpu}, {os.cpu_count()} cores, torch {torch.__version__}"


def results_block(run: Path, marker: str) -> None:
    """The docs block `marker` (on the one docs/*.md page holding it: `update_results.find_page`) from a
    finished run's results.json, its figure copied to docs/figures/<marker>-attention.png."""
    import shutil

    from update_results import DOCS, FIGURES, find_page, replace_block

    page = find_page(ROOT, marker)
    results = json.loads((run / "results.json").read_text())
    figure = ROOT / FIGURES / f"{marker}-attention.png"
    shutil.copyfile(run / "attention.png", figure)
    block = report_markdown(results, figure=str(figure.relative_to(ROOT / DOCS)))
    replace_block(page, marker, block)
    print(f"wrote block {marker} of {page.relative_to(ROOT)} from {run / 'results.json'}")


def main(argv: list[str] | None = None) -> int:
    a = parse_args(argv)
    a.argv = list(sys.argv[1:] if argv is None else argv)
    if a.stage == "write-lerobot":
        write_lerobot(a.npz, a.root, a.camera, a.vlm)
        return 0
    if a.results_block:
        results_block(a.results_block, a.marker)
        return 0
    results = pipeline(a)
    (a.out / "report.md").write_text(report_markdown(results))
    print(report_markdown(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
