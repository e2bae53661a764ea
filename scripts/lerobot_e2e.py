"""The end-to-end proof through LeRobot: Meta-World demos -> LeRobot v3 data set -> gaze priors -> lerobot-train
(smolvla and smolvla_gaze) -> both checkpoints evaluated on the same unseen Meta-World setups.

    .venv/bin/python scripts/lerobot_e2e.py --out runs/lerobot_e2e                       # toy size (defaults)
    .venv/bin/python scripts/lerobot_e2e.py --out runs/e2e --tasks reach-v3 --demos 20 --steps 2000 \
        --eval-episodes 50

Two interpreters: this one (the project venv: gazereg, Meta-World, MuJoCo) and the LeRobot lane's
(`--lane-python`, lerobot 0.6.1 + the plugin). Stages, each a subprocess:
  1. `gazereg collect`: Meta-World scripted-expert demos into an episode store (setup seeds from --demo-seed).
  2. lane: the demos written as a LeRobot v3 data set with lerobot's own `LeRobotDataset.create / add_frame /
     save_episode / finalize`, with a `gaze.point` column: the visuomotor gaze model's per-frame (u, v) trace
     (it needs the simulator's key points, which only the collected store has, so the trace is computed here
     and travels in the data set as recorded gaze).
  3. `gazereg import lerobot` -> `gazereg priors --source recorded` -> `gazereg import write-gaze`: the priors
     as gaze.<camera>.heatmap / .valid in a new data set version.
  4. lane: the real `lerobot-train`, --policy.type=smolvla and smolvla_gaze, same data, seed and steps, from
     scratch on a tiny random SmolVLM (offline, CPU).
  5. both checkpoints on the same unseen setups (seeds from --eval-seed): the rollouts run here, the policy in
     the lane through `lerobot_policy_gazereg.eval_adapter` (LeRobot 0.6.1 has a Meta-World env, but it needs
     metaworld in the lane venv); success with Wilson intervals and the exact McNemar test on the pairs; each
     policy's attention to the image tokens on data set frames next to the prior (OUT/attention.png, KL).
Results: OUT/results.json, and a summary on stdout.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

LANE_PYTHON = Path("/root/.cache/gazereg/lerobot-py312/bin/python")
REPO_ID = "local/metaworld_e2e"
MAX_FAILURES = 20  # extra demo seeds tried per task: demos use seeds demo_seed .. demo_seed + demos + 20
ROOT = Path(__file__).resolve().parents[1]
ADAPTER = ROOT / "lerobot_plugin" / "src" / "lerobot_policy_gazereg" / "eval_adapter.py"
OFFLINE = {"HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "WANDB_MODE": "disabled"}


def _run(cmd: list[str], log: Path) -> None:
    """Run `cmd`, its output into `log`; on failure exit naming the command and the log's tail."""
    env = {**os.environ, **OFFLINE}
    t0 = time.time()
    with log.open("w") as f:
        r = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, env=env)
    if r.returncode != 0:
        tail = log.read_text()[-3000:]
        raise SystemExit(
            f"{tail}\nlerobot_e2e: step failed ({r.returncode}): {' '.join(cmd[:3])} ... (log: {log})"
        )
    print(f"  {log.stem}: {time.time() - t0:.1f} s", flush=True)


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


# ----- stage 5: evaluation ----------------------------------------------------------------------------------------


def _protocol() -> Any:
    """The adapter module's message functions, loaded from its file (this interpreter has no lerobot, and the
    plugin package's __init__ imports it)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("_e2e_protocol", ADAPTER)
    mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod


class PipePolicy:
    """A LeRobot checkpoint served by the lane's `lerobot_policy_gazereg.eval_adapter` over a pipe."""

    def __init__(self, lane_python: str, checkpoint: Path, log: Path):
        proto = _protocol()
        self._read, self._write = proto.read_message, proto.write_message
        self._log = log.open("w")
        cmd = [lane_python, "-m", "lerobot_policy_gazereg.eval_adapter", str(checkpoint)]
        env = {**os.environ, **OFFLINE}
        self.proc = subprocess.Popen(
            cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._log, env=env
        )
        self.ask(None)

    def ask(self, msg: dict[str, Any] | None) -> dict[str, Any]:
        if msg is not None:
            self._write(self.proc.stdin, msg)
        reply = self._read(self.proc.stdout)
        if reply is None or "error" in reply:
            why = "the policy server exited" if reply is None else reply["error"]
            raise SystemExit(f"lerobot_e2e: evaluation failed: {why} (log: {self._log.name})")
        return reply

    def reset(self) -> None:
        self.ask({"op": "reset"})

    def act(self, images: dict[str, np.ndarray], state: np.ndarray, task: str) -> np.ndarray:
        return self.ask({"op": "act", "images": images, "state": state, "task": task})["action"]

    def close(self) -> None:
        try:
            self._write(self.proc.stdin, {"op": "close"})
            self.proc.wait(timeout=60)
        except (OSError, subprocess.TimeoutExpired):  # already gone, or stuck: do not hide the first error
            self.proc.kill()
        self._log.close()


def rollout(policy: PipePolicy, env: Any, seed: int, camera: str) -> tuple[bool, int]:
    """One episode on setup `seed` of `env` (a gazereg Meta-World env): (success, steps)."""
    obs, info = env.reset(seed=seed)
    policy.reset()
    done, steps = False, 0
    while not done:
        images = {f"observation.images.{camera}": obs["images"][camera]}
        action = np.clip(policy.act(images, obs["state"], obs["instruction"]), -1.0, 1.0)
        obs, _, term, trunc, info = env.step(action)
        done, steps = bool(term or trunc), steps + 1
    return bool(info["success"]), steps


def run_arm(policy: PipePolicy, seeds: list[int], a: argparse.Namespace) -> list[tuple[str, int, bool, int]]:
    """(task, seed, success, steps) of every task on every seed."""
    from gazereg.envs.metaworld.env import MetaWorldEnv

    kw: dict[str, Any] = {"max_steps": a.eval_max_steps} if a.eval_max_steps else {}
    runs = []
    for task in a.tasks:
        env = MetaWorldEnv(task, cameras=(a.camera,), image_size=a.image_size, **kw)
        try:
            runs += [(task, s, *rollout(policy, env, s, a.camera)) for s in seeds]
        finally:
            env.close()
    return runs


def evaluate(
    arms: dict[str, Path], a: argparse.Namespace, data: Path, logs: Path
) -> tuple[dict[str, Any], dict[str, dict[str, np.ndarray]]]:
    """Both checkpoints on the same setups: (success per episode, Wilson intervals and exact McNemar on the
    pairs; each arm's attention maps on frames of the data set `data`, see eval_adapter.attention_maps)."""
    from gazereg.evaluation.stats import mcnemar_exact, paired_counts, wilson

    seeds = [a.eval_seed + i for i in range(a.eval_episodes)]
    out: dict[str, Any] = {"setup_seeds": seeds, "arms": {}}
    maps = {}
    ask = {"op": "attention", "root": str(data), "gaze_key": f"gaze.{a.camera}.heatmap"}
    for arm, ckpt in arms.items():
        t0 = time.time()
        policy = PipePolicy(a.lane_python, ckpt, logs / f"eval_{arm}.log")
        try:
            maps[arm] = policy.ask({**ask, "camera": f"observation.images.{a.camera}"})["maps"]
            runs = run_arm(policy, seeds, a)
        finally:
            policy.close()
        ok = [r[2] for r in runs]
        lo, hi = wilson(sum(ok), len(ok))
        out["arms"][arm] = {
            "success": ok,
            "steps": [r[3] for r in runs],
            "rate": sum(ok) / len(ok),
            "wilson95": [lo, hi],
            "seconds": round(time.time() - t0, 1),
        }
        print(f"  eval {arm}: {sum(ok)}/{len(ok)} ({time.time() - t0:.1f} s)", flush=True)
    a_ok, b_ok = (out["arms"][k]["success"] for k in ("smolvla", "smolvla_gaze"))
    out["paired"] = {
        "both_onlysmolvla_onlygaze_neither": paired_counts(a_ok, b_ok),
        "mcnemar": mcnemar_exact(a_ok, b_ok),
    }
    return out, maps


def attention_figure(maps: dict[str, dict[str, np.ndarray]], out: Path) -> dict[str, float | None]:
    """Each arm's attention to the camera's image tokens on the same data set frames (from the eval adapter),
    drawn next to the gaze prior on the token grid into OUT/attention.png; returns {arm: mean KL(gaze ||
    attention) over the frames with gaze}."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    first = next(iter(maps.values()))
    n = len(first["index"])
    fig, ax = plt.subplots(n, 2 + len(maps), figsize=(2.2 * (2 + len(maps)), 2.2 * n), squeeze=False)
    for i in range(n):
        panels = [("frame", first["image"][i]), ("gaze prior (tokens)", first["gaze"][i])]
        panels += [(f"{arm} KL {m['kl'][i]:.2f}", m["attention"][i]) for arm, m in maps.items()]
        for j, (title, img) in enumerate(panels):
            ax[i, j].imshow(img, **({} if j == 0 else {"cmap": "magma"}))
            ax[i, j].set_title(title if j > 1 else f"{title} #{first['index'][i]}", fontsize=7)
            ax[i, j].axis("off")
    fig.tight_layout()
    fig.savefig(out / "attention.png", dpi=100)
    plt.close(fig)
    return {arm: float(m["kl"][m["valid"]].mean()) if m["valid"].any() else None for arm, m in maps.items()}


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
        "--lane-python", default=str(LANE_PYTHON), help="the interpreter with lerobot 0.6.1 + plugin"
    )
    p.add_argument("--stage", default="all", help=argparse.SUPPRESS)  # internal: write-lerobot (lane)
    p.add_argument("--npz", type=Path, help=argparse.SUPPRESS)
    p.add_argument("--root", type=Path, help=argparse.SUPPRESS)
    p.add_argument("--vlm", type=Path, help=argparse.SUPPRESS)
    return p.parse_args(argv)


def pipeline(a: argparse.Namespace) -> dict[str, Any]:
    """Stages 1-5 (module doc) under a.out; returns the results."""
    gz, lane, out = [sys.executable, "-m", "gazereg.cli"], a.lane_python, a.out.resolve()
    if a.eval_seed < a.demo_seed + a.demos + MAX_FAILURES and a.demo_seed < a.eval_seed + a.eval_episodes:
        raise SystemExit(f"lerobot_e2e: evaluation seeds from {a.eval_seed} overlap the demos' setup seeds")
    if out.exists():
        raise SystemExit(f"lerobot_e2e: --out {out} exists; give a new folder")
    if not Path(lane).exists():
        raise SystemExit(f"lerobot_e2e: no LeRobot lane interpreter at {lane} (--lane-python)")
    logs = out / "logs"
    logs.mkdir(parents=True)
    t0, cam = time.time(), a.camera
    collect = [*gz, "collect", f"--out={out / 'collected'}", "--tasks", *a.tasks, f"--episodes={a.demos}"]
    collect += [
        f"--seed-base={a.demo_seed}",
        f"--max-failures={MAX_FAILURES}",
        f"--cameras={cam}",
        f"--image-size={a.image_size}",
        "--no-progress",
    ]
    _run(collect, logs / "1_collect.log")
    export_demos(out / "collected", cam, out / "npz")
    data, data_gaze = out / "lerobot", out / "lerobot_gaze"
    vlm = out / "tiny_smolvlm"
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
    size = [str(a.prior_size)] * 2
    pri = [*gz, "priors", f"--store={store}", "--source=recorded", f"--camera={cam}", "--size", *size]
    _run(pri, logs / "3_priors.log")
    wg = [
        *gz,
        "import",
        "write-gaze",
        f"--store={store}",
        "--prior=recorded",
        f"--root={data}",
        f"--out={data_gaze}",
    ]
    _run([*wg, "--no-progress"], logs / "3_write_gaze.log")
    arms = {}
    for kind in ("smolvla", "smolvla_gaze"):
        _run(train_args(kind, a, data_gaze, vlm, out / f"train_{kind}"), logs / f"4_train_{kind}.log")
        arms[kind] = out / f"train_{kind}" / "checkpoints" / "last" / "pretrained_model"
    results, maps = evaluate(arms, a, data_gaze, logs)
    results["attention_kl_gaze_to_attention"] = attention_figure(maps, out)
    results.update(tasks=a.tasks, demos=a.demos, steps=a.steps, wall_s=round(time.time() - t0, 1))
    (out / "results.json").write_text(json.dumps(results, indent=1))
    return results


def summary(r: dict[str, Any]) -> str:
    lines = [
        f"tasks {r['tasks']}, {r['demos']} demos/task, {r['steps']} training steps, setups {r['setup_seeds']}"
    ]
    for arm, v in r["arms"].items():
        lo, hi = v["wilson95"]
        lines.append(
            f"{arm:13s} success {sum(v['success'])}/{len(v['success'])} = {v['rate']:.2f} [{lo:.2f}, {hi:.2f}]"
        )
    m = r["paired"]["mcnemar"]
    lines.append(
        f"paired: only smolvla {m['a_only']}, only smolvla_gaze {m['b_only']}, McNemar p = {m['p_value']:.3f}"
    )
    kl = ", ".join(f"{k} {v:.3f}" for k, v in r["attention_kl_gaze_to_attention"].items() if v is not None)
    lines.append(f"KL(gaze || attention) on data set frames: {kl} (figure: attention.png)")
    lines.append(f"wall time {r['wall_s']} s")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    a = parse_args(argv)
    if a.stage == "write-lerobot":
        write_lerobot(a.npz, a.root, a.camera, a.vlm)
        return 0
    print(summary(pipeline(a)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
