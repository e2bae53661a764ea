"""Stage 5 of scripts/lerobot_e2e.py: LeRobot checkpoints evaluated on the same unseen Meta-World setups.

The rollouts run in this interpreter (the project venv: Meta-World, MuJoCo); each policy runs in the LeRobot
lane, served by `lerobot_policy_gazereg.eval_adapter` over a pipe (LeRobot 0.6.1 has a Meta-World env, but it
needs metaworld in the lane venv). Success with Wilson intervals, the exact McNemar test on the pairs, and each
policy's attention to the image tokens on data set frames next to the gaze prior (OUT/attention.png).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ADAPTER = ROOT / "lerobot_plugin" / "src" / "lerobot_policy_gazereg" / "eval_adapter.py"
OFFLINE = {"HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "WANDB_MODE": "disabled"}


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
            "task": [r[0] for r in runs],
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


def report_markdown(r: dict[str, Any], figure: str = "attention.png") -> str:
    """The run's results as markdown: the command, the data and budget, GLC's held-out quality, success per
    task and pooled with Wilson intervals, the paired test, the attention KL and the stage times."""
    from gazereg.evaluation.stats import wilson

    lines = [
        f"Command: `{r['command']}` ({r['machine']}, wall time {r['wall_s'] / 60:.1f} min).",
        "",
        f"Tasks {', '.join(r['tasks'])}: {r['demos']} expert demos per task, {r['steps']} lerobot-train steps per "
        f"arm, evaluation on the same {len(r['setup_seeds'])} unseen setups per task (seeds "
        f"{r['setup_seeds'][0]}..{r['setup_seeds'][-1]}); gaze prior: {r['gaze_source']}.",
    ]
    if r.get("glc"):
        g = r["glc"]
        lines += [
            "",
            f"GLC on {g['heldout_episodes']} held-out episodes of its own setups: F1 {g['glc_f1']:.3f} (centre "
            f"prior {g['centre_prior_f1']:.3f}), AUC {g['glc_auc']:.3f} (centre prior {g['centre_prior_auc']:.3f}).",
        ]
    arms = list(r["arms"])
    lines += ["", "| task | " + " | ".join(arms) + " |", "|---" * (len(arms) + 1) + "|"]
    for task in [*r["tasks"], "pooled"]:
        cells = []
        for arm in arms:
            v = r["arms"][arm]
            ok = [s for s, t in zip(v["success"], v["task"]) if task in ("pooled", t)]
            lo, hi = wilson(sum(ok), len(ok))
            cells.append(f"{sum(ok)}/{len(ok)} [{lo:.2f}, {hi:.2f}]")
        lines.append(f"| {task} | " + " | ".join(cells) + " |")
    m = r["paired"]["mcnemar"]
    kl = ", ".join(f"{k} {v:.3f}" for k, v in r["attention_kl_gaze_to_attention"].items() if v is not None)
    times = ", ".join(f"{k} {v / 60:.1f}" for k, v in r["stage_seconds"].items())
    lines += [
        "",
        f"Paired on the setups: only smolvla {m['a_only']}, only smolvla_gaze {m['b_only']}, exact McNemar "
        f"p = {m['p_value']:.3f}. Success cells: successes/episodes [Wilson 95% interval].",
        "",
        f"KL(gaze || attention to the image tokens) on data set frames: {kl}. Stage times (min): {times}.",
        "",
        f"![attention: frame, gaze prior, each arm's attention]({figure})",
    ]
    return "\n".join(lines) + "\n"
