"""`gazereg pretrain`: a generalist VLA trained multi-task with language instructions (no gaze), stage by stage
and resumable, to fine-tune on held-out tasks (`gazereg train --init-from`, `gazereg experiment
--train.init-from`).

    gazereg pretrain                                  # ML45's 45 training tasks (preset ml45; hours on 2 cores)
    gazereg pretrain --preset toy --out runs/pt     # every stage at toy size, seconds
    gazereg pretrain --train.stop-at 10000            # pause training with a checkpoint; rerun to continue
    gazereg pretrain --preset ml45_continued          # 30,000 more steps from the committed generalist

Stages (each writes into `out/` and a marker `out/stages/<name>.json` with its wall time over every attempt
and the git commit it ran at; a rerun skips finished stages and refuses a folder made with another
configuration but for the execution keys, `pretrain_config.EXECUTION_KEYS`):
  demos     Meta-World's scripted experts on the tasks, on setups of their own (PRETRAIN_DEMOS, from seed
            100,000: gazereg.envs.metaworld.setups), into out/demos (`gazereg.envs.collect.collect`, which
            resumes an interrupted collection)
  train     one multi-task policy conditioned on each task's instruction (a words vocabulary that holds
            ML45's held-out instructions too: pretrain_config) into out/train (`gazereg.training.loop.train`,
            resumed from its newest checkpoint); its final weights are copied to out/policy, the folder to
            fine-tune from
  eval      out/policy on PRETRAIN_EVAL setups of every task, clean, into out/eval
            (`gazereg.evaluation.rollout.evaluate`, resumed from its episode log)
  manifest  out/manifest.json: the command line, git commit, the demonstrations' fingerprint (of every
            episode's fingerprint), the SHA-256 of out/policy/model.safetensors, the parameter count, the
            numerics key, the config, the saved policy the training started from (`init_from`: its path and
            SHA-256; None from scratch), each stage's wall time, the multi-task success, and the options that give
            a fine-tuning run this policy's architecture (`finetune_flags`)

Presets and checks: `gazereg.experiment.pretrain_config`; the study around it: docs/pretraining.md.
"""

from __future__ import annotations

import json
import logging
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

from gazereg.data.store import EpisodeStore
from gazereg.envs.collect import collect
from gazereg.envs.collect_config import CollectConfig
from gazereg.envs.metaworld.setups import PRETRAIN_DEMOS, PRETRAIN_EVAL
from gazereg.envs.recording import versions
from gazereg.evaluation.config import EvalConfig
from gazereg.evaluation.rollout import evaluate
from gazereg.experiment.demos import collection_result
from gazereg.experiment.pretrain_config import (
    DEFAULT_PRESET,
    EXECUTION_KEYS,
    PRESETS,
    PretrainConfig,
    finetune_flags,
    preflight,
)
from gazereg.experiment.records import with_added_keys
from gazereg.policies.base import CONFIG_FILE, MODEL_FILE, TOKENIZER_FILE
from gazereg.runtime.clock import ResumableClock
from gazereg.runtime.config import check_same_config, parse_named, save_config, to_dict
from gazereg.runtime.errors import Terminated, annotate_interruption
from gazereg.runtime.hardware import NumericsKey
from gazereg.runtime.io import atomic_dir, atomic_write_json, sweep_stale_temps
from gazereg.runtime.pool import fingerprint_json
from gazereg.training.checkpoint import latest_checkpoint, list_checkpoints
from gazereg.training.init_from import INIT_RECORD, file_sha256
from gazereg.training.loop import train
from gazereg.training.numerics import read_numerics

log = logging.getLogger(__name__)

STAGES = ("demos", "train", "eval", "manifest")
ARM = "pretrained"
"""the evaluation's name for the pretrained policy"""


def git_commit(cwd: Path | None = None) -> dict[str, Any]:
    """{"commit": HEAD's hash or None outside a git checkout, "dirty": uncommitted changes to tracked files}."""
    where = cwd or Path(__file__).resolve().parent

    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(["git", *args], cwd=where, capture_output=True, text=True, timeout=30)
        except (OSError, subprocess.SubprocessError):
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    status = git("status", "--porcelain", "--untracked-files=no") if commit else None
    return {"commit": commit, "dirty": bool(status) if status is not None else None}


def store_fingerprint(store: EpisodeStore) -> str:
    """16 hex digits over every episode's index and fingerprint: equal demonstrations, equal value."""
    return fingerprint_json([[i, store.episode_fingerprint(i)] for i in store.indices()])


class Paused(Exception):
    """The training stage stopped at --train.stop-at before its last step (a rerun continues it)."""


class Pretraining:
    """The stages of one pretraining run folder (module docstring)."""

    def __init__(self, cfg: PretrainConfig, preset: str = "custom", argv: list[str] | None = None):
        self.cfg, self.preset, self.argv = cfg, preset, list(argv or [])
        self.out = Path(cfg.out)
        self.demos, self.train_dir = self.out / "demos", self.out / "train"
        self.policy_dir, self.eval_dir = self.out / "policy", self.out / "eval"

    # ----- bookkeeping ------------------------------------------------------------------------------------
    def marker(self, stage: str) -> Path:
        return self.out / "stages" / f"{stage}.json"

    def done(self, stage: str) -> dict[str, Any] | None:
        m = self.marker(stage)
        return json.loads(m.read_text()) if m.exists() else None

    def check_resumable(self) -> None:
        """Refuse a folder whose finished stages were made with another configuration; a key added to the
        configuration since the folder was made counts as its default (`records.with_added_keys`)."""
        saved = self.out / "config.json"
        if saved.exists():
            check_same_config(
                with_added_keys(json.loads(saved.read_text()), to_dict(PretrainConfig()), to_dict(self.cfg)),
                self.cfg,
                EXECUTION_KEYS,
                self.out,
                "its finished stages would be reused. Choose another --out, or delete the folder to start over.",
            )

    def run(self) -> dict[str, Any]:
        """Every stage not finished yet; returns each stage's record. Raises `Paused` when training stopped at
        --train.stop-at."""
        self.check_resumable()
        preflight(self.cfg)
        self.out.mkdir(parents=True, exist_ok=True)
        sweep_stale_temps(self.out)
        save_config(self.cfg, self.out / "config.json")
        results: dict[str, Any] = {}
        for stage in STAGES:
            prev = self.done(stage)
            if prev is not None:
                log.info("stage %s: done earlier, skipping", stage)
                results[stage] = prev
                continue
            log.info("stage %s ...", stage)
            try:
                with ResumableClock(self.out / "stages" / f"{stage}.clock.json") as clock:
                    res = getattr(self, f"stage_{stage}")(results)
            except (KeyboardInterrupt, Terminated) as e:
                annotate_interruption(e, f"stage {stage}", "rerun the same command to resume")
                raise
            results[stage] = {**res, "seconds": clock.seconds, "git": git_commit()}
            atomic_write_json(self.marker(stage), results[stage])
            clock.clear()
        return results

    # ----- stages -----------------------------------------------------------------------------------------
    def collect_config(self) -> CollectConfig:
        c = self.cfg
        return CollectConfig(
            out=self.demos,
            tasks=c.tasks,
            episodes=c.demos_per_task,
            max_failures=c.demo_max_failures,
            seed_base=PRETRAIN_DEMOS.start,
            cameras=(c.camera,),
            image_size=c.image_size,
            max_steps=c.demo_max_steps,
            workers=c.collect_workers,
            progress=c.progress,
        )

    def stage_demos(self, _: dict[str, Any]) -> dict[str, Any]:
        """The demonstrations; every task must keep at least one (`experiment.demos.collection_result`)."""
        report = collect(self.collect_config())
        return {
            **collection_result("train", report, EpisodeStore(self.demos)),
            "seeds": [PRETRAIN_DEMOS.start],
        }

    def train_config(self) -> Any:
        c, t = self.cfg, self.cfg.train
        return replace(
            t,
            run_dir=self.train_dir,
            data=replace(t.data, store=self.demos),
            progress=t.progress and c.progress,
        )

    def stage_train(self, _: dict[str, Any]) -> dict[str, Any]:
        """Train (resuming from the newest checkpoint), then copy the final weights to out/policy."""
        cfg = self.train_config()
        finished = [s for s, _ in list_checkpoints(self.train_dir) if s >= cfg.steps]
        metrics: dict[str, Any] = {}
        if not finished:
            resume = latest_checkpoint(self.train_dir) is not None
            res = train(replace(cfg, resume=resume))
            metrics = res["metrics"]
            if int(res["step"]) < cfg.steps:
                raise Paused(f"training paused at step {res['step']} of {cfg.steps} (--train.stop-at)")
        final = latest_checkpoint(self.train_dir)
        assert final is not None
        with atomic_dir(self.policy_dir) as tmp:
            for name in (MODEL_FILE, CONFIG_FILE, TOKENIZER_FILE):
                shutil.copy2(final / name, tmp / name)
        return {"checkpoint": str(final), "policy": str(self.policy_dir), "final_metrics": metrics}

    def eval_config(self) -> EvalConfig:
        c = self.cfg
        return EvalConfig(
            checkpoints=(f"{ARM}={self.policy_dir}",),
            tasks=c.tasks,
            episodes=c.eval_episodes,
            seed_start=PRETRAIN_EVAL.start,
            conditions=("clean",),
            max_steps=c.eval_max_steps,
            workers=c.eval_workers,
            batch=c.eval_batch,
            videos=0,
            out=self.eval_dir,
            env="metaworld",
        )

    def stage_eval(self, _: dict[str, Any]) -> dict[str, Any]:
        """Multi-task success of out/policy on the evaluation setups: pooled and per task (Wilson 95%)."""
        info = evaluate(self.eval_config(), progress=self.cfg.progress)
        clean = info["summary"]["arms"][ARM]["clean"]
        return {
            "eval_info": str(self.eval_dir / "eval_info.json"),
            "pooled": clean["pooled"],
            "tasks": clean["tasks"],
        }

    def stage_manifest(self, results: dict[str, Any]) -> dict[str, Any]:
        manifest = self.manifest(results)
        atomic_write_json(self.out / "manifest.json", manifest)
        return {
            "manifest": str(self.out / "manifest.json"),
            "model_sha256": manifest["policy"]["model_sha256"],
        }

    def manifest(self, results: dict[str, Any]) -> dict[str, Any]:
        """What the manifest records (module docstring)."""
        store = EpisodeStore(self.demos)
        trained = json.loads((self.train_dir / "config.json").read_text())
        n_params = sum(int(v) for v in _tensor_sizes(self.policy_dir / MODEL_FILE).values())
        return {
            "command": ["gazereg", "pretrain", *self.argv],
            "preset": self.preset,
            "git": git_commit(),
            "data": {
                "store": str(self.demos),
                "episodes": len(store),
                "frames": results["demos"]["frames"],
                "fingerprint": store_fingerprint(store),
                "setup_seeds": [PRETRAIN_DEMOS.start, PRETRAIN_DEMOS.stop],
            },
            "policy": {
                "folder": str(self.policy_dir),
                "model_sha256": file_sha256(self.policy_dir / MODEL_FILE),
                "parameters_and_buffers": n_params,
                "finetune_flags": finetune_flags(self.cfg.train.policy),
            },
            "init_from": _init_record(self.train_dir),
            "numerics": NumericsKey.here(trained["mixed_precision"]).to_dict(),
            "training_attempts": _attempts(self.train_dir),
            "evaluation": {
                "setup_seeds": [PRETRAIN_EVAL.start, PRETRAIN_EVAL.start + self.cfg.eval_episodes],
                "pooled": results["eval"]["pooled"],
                "tasks": {t: r["rate"] for t, r in results["eval"]["tasks"].items()},
            },
            "stage_seconds": {s: results[s]["seconds"] for s in STAGES if s in results},
            "versions": versions(("gazereg", "torch", "metaworld", "mujoco")),
            "config": to_dict(self.cfg),
        }


def _init_record(train_dir: Path) -> dict[str, Any] | None:
    """The saved policy the training started from (its path and weights' SHA-256), None from scratch."""
    path = train_dir / INIT_RECORD
    return json.loads(path.read_text()) if path.exists() else None


def _attempts(train_dir: Path) -> list[dict[str, Any]] | None:
    """The numerics key of each training attempt (`training.numerics`: where the train stage ran, which may
    differ from where the manifest is written, `numerics`); None for training made before it was recorded."""
    attempts = read_numerics(train_dir)
    return None if attempts is None else [a.to_dict() for a in attempts]


def _tensor_sizes(path: Path) -> dict[str, int]:
    """Element count of every tensor of a safetensors file, read from its header."""
    with open(path, "rb") as f:
        n = int.from_bytes(f.read(8), "little")
        header = json.loads(f.read(n))
    out = {}
    for name, meta in header.items():
        if name != "__metadata__":
            size = 1
            for d in meta["shape"]:
                size *= int(d)
            out[name] = size
    return out


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    args = list(sys.argv[1:] if argv is None else argv)
    preset, cfg = parse_named(
        PRESETS, args, prog="gazereg pretrain", description=__doc__ or "", default=DEFAULT_PRESET
    )
    try:
        results = Pretraining(cfg, preset, args).run()
    except Paused as e:
        print(f"{e}; rerun the command (with a later --train.stop-at, or without it) to continue")
        return 0
    ev = results["eval"]["pooled"]
    print(json.dumps({"policy": str(Path(cfg.out) / "policy"), "success": ev["rate"], "ci95": ev["ci95"]}))
    print(
        f"fine-tune with: --train.init-from {Path(cfg.out) / 'policy'} {' '.join(finetune_flags(cfg.train.policy))}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
