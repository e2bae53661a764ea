"""Stage 5 of scripts/lerobot_e2e.py: LeRobot checkpoints evaluated on the same unseen Meta-World setups.

The rollouts run in this interpreter (the project venv: Meta-World, MuJoCo) through gazereg's own evaluation
(`gazereg.evaluation.rollout`: its jobs, its worker's episode loop and records); each policy runs in the LeRobot
lane, served by `lerobot_policy_gazereg.eval_adapter` over a pipe (LeRobot 0.6.1 has a Meta-World env, but it
needs metaworld in the lane venv) and stands in for a gazereg policy in the rollout worker (`LaneWorker`).
Success with Wilson intervals (`gazereg.report.tables.success_table`), the exact McNemar test on the pairs
(`gazereg.evaluation.stats`), and each policy's attention to the image tokens on data set frames next to the
gaze prior (OUT/attention.png).
"""

from __future__ import annotations

import argparse
import functools
import os
import subprocess
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gazereg.evaluation.config import EvalConfig
from gazereg.evaluation.rollout import RolloutWorker, make_jobs, run_jobs
from gazereg.evaluation.stats import mcnemar_exact, paired_counts
from gazereg.report.ids import RunId
from gazereg.report.tables import run_of, success_table

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


@dataclass(frozen=True)
class LaneConfig:
    """What gazereg's rollout worker reads of a policy's config: the cameras it sees and their image size."""

    cameras: tuple[str, ...]
    image_hw: tuple[int, int]
    camera_hw: tuple[tuple[int, int], ...] | None = None


class LanePolicy:
    """A served LeRobot checkpoint (`PipePolicy`, or anything with `reset()` and `act(images, state, task)`) as
    gazereg's rollout worker drives a policy: `config`, `reset()`, `select_action(batch, instructions)`."""

    def __init__(self, served: Any, camera: str, image_size: int):
        self.served, self.config = served, LaneConfig((camera,), (image_size, image_size))

    def reset(self) -> None:
        self.served.reset()

    def select_action(self, batch: dict[str, Any], instructions: Sequence[str]) -> np.ndarray:
        """(n, A) actions in [-1, 1] for a batch of n observations: `batch["state"]` (n, S), `batch["images"]`
        {camera: uint8 (n, H, W, 3)}; one request to the server per observation."""
        actions = []
        for i, task in enumerate(instructions):
            images = {f"observation.images.{c}": frames[i] for c, frames in batch["images"].items()}
            actions.append(np.clip(self.served.act(images, batch["state"][i], task), -1.0, 1.0))
        return np.stack(actions)


class LaneWorker(RolloutWorker):
    """gazereg's rollout worker (environments, episode loop, records) acting with one `LanePolicy` for every
    checkpoint it is given (the policy is served, not loaded here)."""

    def __init__(self, policy: LanePolicy, max_steps: int):
        super().__init__(max_steps, None, "metaworld", batch=1)
        self.lane_policy = policy

    def policy(self, checkpoint: str) -> LanePolicy:
        return self.lane_policy


def eval_config(a: argparse.Namespace, out: Path) -> EvalConfig:
    """The evaluation both arms get: `a.tasks`, `a.eval_episodes` setups from `a.eval_seed`, clean, one
    episode at a time in this process, `a.eval_max_steps` steps (0: Meta-World's limit)."""
    from gazereg.envs.metaworld.env import MAX_PATH_LENGTH

    return EvalConfig(
        tasks=tuple(a.tasks),
        episodes=a.eval_episodes,
        seed_start=a.eval_seed,
        conditions=("clean",),
        max_steps=a.eval_max_steps or MAX_PATH_LENGTH,
        workers=1,
        batch=1,
        videos=0,
        out=out,
        env="metaworld",
    )


def rollouts(policy: LanePolicy, run: RunId, checkpoint: Path, cfg: EvalConfig) -> list[dict[str, Any]]:
    """gazereg's evaluation records (`gazereg.evaluation.rollout`: arm, task, condition, seed, success, length
    ...) of `policy` on every task and setup of `cfg`, named `run`."""
    jobs = make_jobs(cfg, {str(run): checkpoint})
    worker = functools.partial(LaneWorker, policy, cfg.max_steps)
    return run_jobs(jobs, cfg, progress=False, make_worker=worker)


def arm_results(records: list[dict[str, Any]], arm: str) -> dict[str, Any]:
    """One arm's entry of results.json: per episode (task-major, then setup) its success, steps and task, and
    the pooled rate with its Wilson 95% interval."""
    mine = [r for r in records if run_of(r).arm == arm]
    cell = success_table(mine)[arm]["clean"]
    return {
        "success": [bool(r["success"]) for r in mine],
        "steps": [int(r["length"]) for r in mine],
        "task": [r["task"] for r in mine],
        "rate": cell["rate"],
        "wilson95": cell["ci95"],
    }


def evaluate(
    arms: dict[str, Path], a: argparse.Namespace, data: Path, logs: Path
) -> tuple[dict[str, Any], dict[str, dict[str, np.ndarray]]]:
    """Both checkpoints on the same setups: (success per episode, Wilson intervals and exact McNemar on the
    pairs; each arm's attention maps on frames of the data set `data`, see eval_adapter.attention_maps)."""
    cfg = eval_config(a, logs / "eval")
    out: dict[str, Any] = {"setup_seeds": list(cfg.seeds("clean")), "arms": {}}
    maps = {}
    ask = {"op": "attention", "root": str(data), "gaze_key": f"gaze.{a.camera}.heatmap"}
    for arm, ckpt in arms.items():
        t0 = time.time()
        served = PipePolicy(a.lane_python, ckpt, logs / f"eval_{arm}.log")
        try:
            maps[arm] = served.ask({**ask, "camera": f"observation.images.{a.camera}"})["maps"]
            records = rollouts(LanePolicy(served, a.camera, a.image_size), RunId(arm, a.seed), ckpt, cfg)
        finally:
            served.close()
        out["arms"][arm] = {**arm_results(records, arm), "seconds": round(time.time() - t0, 1)}
        ok = out["arms"][arm]["success"]
        print(f"  eval {arm}: {sum(ok)}/{len(ok)} ({time.time() - t0:.1f} s)", flush=True)
    a_ok, b_ok = (out["arms"][k]["success"] for k in ("smolvla", "smolvla_gaze"))
    out["paired"] = {
        "both_onlysmolvla_onlygaze_neither": paired_counts(a_ok, b_ok),
        "mcnemar": mcnemar_exact(a_ok, b_ok),
    }
    return out, maps


def episode_records(r: dict[str, Any]) -> list[dict[str, Any]]:
    """The evaluation records (gazereg's form, clean) behind results.json's per-arm lists: each arm's episodes
    run task by task over the same setup seeds."""
    seeds = r["setup_seeds"]
    records = []
    for arm, v in r["arms"].items():
        for i, (task, success) in enumerate(zip(v["task"], v["success"])):
            records.append(
                {"arm": f"{arm}@s0", "task": task, "condition": "clean", "seed": seeds[i % len(seeds)],
                 "success": bool(success)}
            )  # fmt: skip
    return records


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
    table = success_table(episode_records(r))
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
            clean = table[arm]["clean"]
            c = clean if task == "pooled" else clean["per_task"][task]
            lo, hi = c["ci95"]
            cells.append(f"{c['successes']}/{c['n']} [{lo:.2f}, {hi:.2f}]")
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
