"""Evaluation speed: closed-loop rollout env steps/s against raw simulation + rendering, printed as JSON.

    python benchmarks/bench_eval.py [--task reach-v3] [--steps 150] [--rounds 3] [--calls 60]

In this process pinned to one core (the GL renderer's threads too) with one torch thread, as an evaluation
worker runs, on environments built by `RolloutWorker.env` (corner2 at 96 px, max_steps and the clean condition
as `gazereg eval` uses them; setup seeds from 1000, a new episode when one ends):
- raw: env steps/s with Meta-World's scripted expert acting (physics + rendering the camera);
- closed loop: env steps/s with a freshly built (random-weight) reference VLA policy choosing every action
  through `select_action(obs, obs["instruction"])`, as `RolloutWorker.run` does; raw and closed-loop steps are
  interleaved over rounds, and resets are timed apart (the expert ends episodes early by succeeding, the
  untrained policy runs to max_steps), so `eval_over_raw` compares steps alone;
- `RolloutWorker.run` itself on that policy saved as a checkpoint (whole episodes, resets included), one
  episode at a time and `EvalConfig().lockstep()` episodes in lockstep (the untrained policy never succeeds, so
  every episode of a batch runs to max_steps: the best case for lockstep);
- `select_action` alone per call on a real observation, float32 and under bf16 autocast;
- `select_action` on a batch of B observations (as one worker stepping B environments in lockstep would
  call it), ms per environment for B in --batches, float32 and bf16 autocast, and the ratio to batch 1;
- physics alone (no camera) for scale.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from _timing import machine_info, run_times

from gazereg.envs import Expert
from gazereg.envs.render import select_gl_backend
from gazereg.evaluation.config import EvalConfig
from gazereg.evaluation.rollout import Job, RolloutWorker
from gazereg.policies.vla import Tokenizer, VLAConfig, VLAPolicy

EVAL_DEFAULTS = {f.name: f.default for f in dataclasses.fields(EvalConfig)}
CAMERA, SIZE = "corner2", (96, 96)


class Loop:
    """Steps one environment with `act(obs)`, timing the action choice, env.step and resets apart."""

    def __init__(
        self, env: Any, act: Callable[[dict], np.ndarray], on_reset: Callable[[], None] = lambda: None
    ):
        self.env, self.act, self.on_reset = env, act, on_reset
        self.seed = EVAL_DEFAULTS["seed_start"]
        self.obs, _ = env.reset(seed=self.seed)
        on_reset()
        self.s = {"act": 0.0, "env": 0.0, "reset": 0.0}
        self.n = self.resets = 0

    def run(self, n: int) -> None:
        for _ in range(n):
            t0 = time.perf_counter()
            action = self.act(self.obs)
            t1 = time.perf_counter()
            self.obs, _, terminated, truncated, _ = self.env.step(action)
            t2 = time.perf_counter()
            self.s["act"] += t1 - t0
            self.s["env"] += t2 - t1
            self.n += 1
            if terminated or truncated:
                self.seed += 1
                self.obs, _ = self.env.reset(seed=self.seed)
                self.on_reset()
                self.s["reset"] += time.perf_counter() - t2
                self.resets += 1

    def summary(self) -> dict[str, float]:
        step_s = self.s["act"] + self.s["env"]
        return {
            "steps_per_s": round(self.n / step_s, 1),
            "steps_per_s_with_resets": round(self.n / (step_s + self.s["reset"]), 1),
            "act_ms_per_step": round(1000 * self.s["act"] / self.n, 3),
            "env_step_ms_per_step": round(1000 * self.s["env"] / self.n, 3),
            "reset_ms": round(1000 * self.s["reset"] / max(self.resets, 1), 1),
            "steps": self.n,
            "resets": self.resets,
        }


def make_policy(instruction: str, state_dim: int, action_dim: int, seed: int = 0) -> VLAPolicy:
    """The tiny reference VLA as benchmarks/bench_train.py builds it, for this env's camera and dims."""
    torch.manual_seed(seed)
    tok = Tokenizer.build([instruction], max_len=VLAConfig().max_text_len)
    data = {"cameras": (CAMERA,), "camera_hw": (SIZE,), "state_dim": state_dim, "action_dim": action_dim}
    return VLAPolicy(VLAConfig(**data, vocab_size=tok.vocab_size), tok)


def select_action_ms(policy: VLAPolicy, obs: dict, rounds: int, calls: int) -> dict[str, float]:
    """Median ms per `select_action` call (n_action_steps=1: a chunk every call), float32 and bf16 autocast."""
    times: dict[str, list[float]] = {"float32": [], "bf16_autocast": []}
    policy.reset()
    for _ in range(rounds):
        for mode, v in times.items():
            amp = mode == "bf16_autocast"
            for i in range(calls + 2):
                with torch.autocast("cpu", dtype=torch.bfloat16, enabled=amp):
                    t0 = time.perf_counter()
                    policy.select_action(obs, obs["instruction"])
                    dt = time.perf_counter() - t0
                if i >= 2:  # the first calls after switching mode are warm-up
                    v.append(dt)
    return {k: round(1000 * statistics.median(v), 3) for k, v in times.items()}


def batched_ms_per_env(
    policy: VLAPolicy, obs: dict, batches: tuple[int, ...], rounds: int, calls: int
) -> dict[str, dict[str, float]]:
    """Median ms per environment of one `select_action` call on B stacked copies of `obs`, per precision."""
    out: dict[str, dict[str, float]] = {"float32": {}, "bf16_autocast": {}}
    for mode, per_b in out.items():
        amp = mode == "bf16_autocast"
        for b in batches:
            stacked = {
                "state": np.stack([obs["state"]] * b),
                "images": {CAMERA: np.stack([obs["images"][CAMERA]] * b)},
            }
            policy.reset()
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=amp):
                times = run_times(
                    lambda s=stacked: policy.select_action(s, obs["instruction"]), rounds * calls, 2
                )
            per_b[str(b)] = round(1000 * statistics.median(times) / b, 3)
    return out


def rollout_worker(
    worker: RolloutWorker, ckpt: Path, task: str, episodes: int, batch: int
) -> dict[str, float]:
    """`RolloutWorker.run` over whole episodes, `batch` at a time in lockstep (policy already loaded): env
    steps/s with resets."""
    worker.policy(str(ckpt))  # loaded once per worker, outside the timing, and the environments made
    for slot in range(batch):
        worker.env(task, (CAMERA,), SIZE, slot)
    jobs = [
        Job("bench", str(ckpt), task, "clean", EVAL_DEFAULTS["seed_start"] + i, None) for i in range(episodes)
    ]
    steps, t0 = 0, time.perf_counter()
    for i in range(0, episodes, batch):
        steps += sum(r["length"] for r in worker.run(jobs[i : i + batch]))
    wall = time.perf_counter() - t0
    return {"steps_per_s": round(steps / wall, 1), "episodes": episodes, "steps": steps, "batch": batch}


def physics_only(task: str, steps: int) -> float:
    from gazereg.envs import MetaWorldEnv

    env = MetaWorldEnv(task, cameras=(), max_steps=EVAL_DEFAULTS["max_steps"])
    expert = Expert(task)
    loop = Loop(env, lambda obs: expert(env.raw_obs))
    loop.run(steps)
    env.close()
    return loop.summary()["steps_per_s"]


def compare_loops(out: dict, raw_env: Any, env: Any, policy: VLAPolicy, args: argparse.Namespace) -> Loop:
    """Raw (expert) and closed-loop (policy) env steps, interleaved over rounds; returns the closed loop."""
    expert = Expert(args.task)
    raw = Loop(raw_env, lambda o: expert(raw_env.raw_obs))
    closed = Loop(env, lambda o: policy.select_action(o, o["instruction"]), policy.reset)
    raw.run(20)  # warm-up, not counted
    closed.run(20)
    raw, closed = Loop(raw_env, raw.act), Loop(env, closed.act, policy.reset)
    for _ in range(args.rounds):
        raw.run(args.steps)
        closed.run(args.steps)
    r, c = raw.summary(), closed.summary()
    out["raw_expert_render"] = r
    out["closed_loop_policy"] = c
    out["eval_over_raw"] = round(c["steps_per_s"] / r["steps_per_s"], 3)
    out["eval_over_raw_with_resets"] = round(c["steps_per_s_with_resets"] / r["steps_per_s_with_resets"], 3)
    step_ms = c["act_ms_per_step"] + c["env_step_ms_per_step"]
    out["closed_loop_split_ms_per_step"] = {
        "render_physics": c["env_step_ms_per_step"],
        "policy": c["act_ms_per_step"],
        "policy_fraction": round(c["act_ms_per_step"] / step_ms, 3),
    }
    return closed


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="reach-v3")
    ap.add_argument("--steps", type=int, default=150, help="env steps per loop per round")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--calls", type=int, default=60, help="select_action calls per precision per round")
    ap.add_argument("--episodes", type=int, default=2, help="RolloutWorker.run episodes")
    ap.add_argument(
        "--batches", type=int, nargs="+", default=[1, 4, 8, 16], help="batched select_action sizes"
    )
    args = ap.parse_args()
    backend = select_gl_backend()
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core, before any GL context spawns threads
    max_steps = EVAL_DEFAULTS["max_steps"]
    raw_worker = RolloutWorker(max_steps, backend)  # sets torch to 1 thread, as in evaluation
    batch = EvalConfig().lockstep()
    worker = RolloutWorker(max_steps, backend, batch=batch)
    out: dict[str, Any] = {
        "machine": machine_info(gl_backend=backend, pinned_cores=sorted(os.sched_getaffinity(0))),
        "task": args.task,
        "camera": CAMERA,
    }
    out.update(image_hw=SIZE, max_steps=max_steps)
    raw_env = raw_worker.env(args.task, (CAMERA,), SIZE)
    env = worker.env(args.task, (CAMERA,), SIZE)
    obs, _ = env.reset(seed=0)
    policy = make_policy(obs["instruction"], obs["state"].shape[-1], env.action_space.shape[-1])
    policy.eval()
    out["policy"] = {"parameters": policy.num_parameters(), "tokens": policy.n_tokens, "weights": "random"}

    closed = compare_loops(out, raw_env, env, policy, args)
    out["select_action_ms"] = sa = select_action_ms(policy, closed.obs, args.rounds, args.calls)
    out["select_action_bf16_over_fp32"] = round(sa["bf16_autocast"] / sa["float32"], 3)
    out["batched_select_action_ms_per_env"] = per_env = batched_ms_per_env(
        policy, closed.obs, tuple(args.batches), args.rounds, args.calls // 4 or 1
    )
    one = per_env["float32"][str(args.batches[0])]
    out["batched_ms_per_env_over_fp32_batch_first"] = {
        mode: {b: round(ms / one, 3) for b, ms in v.items()} for mode, v in per_env.items()
    }
    with tempfile.TemporaryDirectory() as tmp:
        ckpt = policy.save_pretrained(Path(tmp) / "ckpt")
        out["rollout_worker_run"] = rw = rollout_worker(worker, ckpt, args.task, args.episodes, 1)
        out["rollout_worker_run_batched"] = rb = rollout_worker(
            worker, ckpt, args.task, batch * args.episodes, batch
        )
    out["rollout_worker_batched_over_single"] = round(rb["steps_per_s"] / rw["steps_per_s"], 3)
    raw_sps = out["raw_expert_render"]["steps_per_s_with_resets"]
    out["rollout_worker_over_raw_with_resets"] = round(rw["steps_per_s"] / raw_sps, 3)
    out["physics_only_steps_per_s"] = physics_only(args.task, args.steps * args.rounds)
    raw_worker.close()
    worker.close()
    out["machine"]["load_avg_after"] = [round(x, 2) for x in os.getloadavg()]
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
