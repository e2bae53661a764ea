"""`gazereg experiment`: the whole pipeline, stage by stage, resumable (the README's main job).

    gazereg experiment --preset demo             # make demo: the generalist fine-tuned on 2 held-out tasks
    gazereg experiment --preset quick            # 2 Meta-World tasks from scratch, baseline and gaze
    gazereg experiment --preset smoke            # CI: the same code, tiny sizes
    gazereg experiment --preset paper --train-seeds 0 --out runs/paper-s0   # powered: 5 arms, one seed a sitting
    gazereg experiment --preset sweep            # 8 more Meta-World tasks drawn from the difficulty groups
    gazereg experiment --preset full             # every ablation arm, 5 tasks, 128 px: for a many-core GPU machine
    bash scripts/libero_env.sh gazereg experiment --preset libero   # LIBERO-Spatial's 10 tasks, 4 arms

How long each takes on 2 cores: the README's preset table.

Before the first stage, `preflight` checks everything that can be checked without doing the work (tasks,
the training tasks, a given GLC checkpoint, every gaze source; the options themselves are checked when the
configuration is built, --train.gaze.layers against the policy's depth among them): a mistake is one line,
exit 2, before anything is collected.

Stages (each writes into `out/` and a marker `out/stages/<name>.json`; a rerun skips finished stages, so a
killed run loses at most the stage it was in; training resumes from its last checkpoint and evaluation
from its episode log, episodes.jsonl). A stage's time (`seconds` in its marker, the report's stage_times_s)
is the sum over every attempt at it, interrupted ones included: Ctrl-C and SIGTERM save the interrupted
attempt's time as the run unwinds (the command then says which stage stopped: "terminated (SIGTERM) during
stage eval; rerun the same command to resume", exit 143), a SIGKILL loses at most the last 30 s of it
(`gazereg.runtime.clock.ResumableClock`):
  demos      scripted experts on training setups (seeds 0..demos_per_task-1) + held-out setups for alignment
             (`gazereg.experiment.demos`)
  priors     one prior per gaze source an arm needs (the gaze source, and its perturbed controls); for the glc
             arm first its GLC, or one per fold (`gazereg.experiment.glc`)
  train      every arm x training seed with the same budget; arms differ only in their gaze prior
  eval       final checkpoints on shared unseen setups, clean and perturbed (lighting, sensor noise)
  converge   intermediate checkpoints, clean, for success-versus-steps curves
  align      attention vs gaze on held-out frames; the attention figure
  report     report.json, report.md, figures

Arms: baseline (no gaze term), gaze (the gaze source), perturbed (its patches shuffled), blobs (random
blobs), other_episode (another episode's gaze), same_task (another demonstration of the same task's gaze),
saliency, uniform, glc, location (the gaze prior predicted by a training-only head from the image features
instead of imposed on attention: the control for the location information the prior carries).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from gazereg.data.store import EpisodeStore
from gazereg.envs.base import make_collector
from gazereg.envs.collect import collect
from gazereg.evaluation.alignment import alignment_report, attention_maps
from gazereg.evaluation.config import EvalConfig
from gazereg.evaluation.rollout import evaluate
from gazereg.experiment.arms import PriorSpec, arm_prior, gaze_prior, gaze_target, trains_glc
from gazereg.experiment.config import EXECUTION_KEYS, ExperimentConfig
from gazereg.experiment.demos import collection_result, demo_collections, demo_stores
from gazereg.experiment.finished import (
    CONFIG_FILE,
    EVAL_INFO,
    STAGES,
    read_run,
    read_saved_config,
    read_stage,
    run_dir,
    stage_marker,
)
from gazereg.experiment.glc import train_glc, train_glc_folds
from gazereg.experiment.preflight import preflight
from gazereg.experiment.records import as_saved_now, report_spec
from gazereg.gaze.priors import PriorsConfig, make_priors
from gazereg.policies import load_policy
from gazereg.report.build import build_report, write_report
from gazereg.report.figures import attention_panels, plot_attention
from gazereg.report.ids import RunId
from gazereg.runtime.clock import ResumableClock
from gazereg.runtime.config import check_same_config, save_config
from gazereg.runtime.errors import Terminated, UsageError, annotate_interruption
from gazereg.runtime.io import atomic_write_json, sweep_stale_temps
from gazereg.runtime.pool import exit_with_parent
from gazereg.training.checkpoint import latest_checkpoint, list_checkpoints
from gazereg.training.config import TrainConfig
from gazereg.training.loop import train

log = logging.getLogger(__name__)


class Experiment:
    def __init__(self, cfg: ExperimentConfig, preset: str = "custom"):
        self.cfg, self.preset = cfg, preset
        self.out = Path(cfg.out)
        stores = demo_stores(self.out)
        self.store, self.heldout, self.glc_store = stores["train"], stores["heldout"], stores["glc"]
        self.times: dict[str, float] = {}

    # ----- bookkeeping ------------------------------------------------------------------------------------
    def marker(self, stage: str) -> Path:
        return stage_marker(self.out, stage)

    def done(self, stage: str) -> dict[str, Any] | None:
        """`stage`'s record, or None when it has not finished in this folder."""
        return read_stage(self.out, stage)

    def finish(self, stage: str, result: dict[str, Any], seconds: float) -> dict[str, Any]:
        atomic_write_json(self.marker(stage), {**result, "seconds": seconds})
        return result

    def check_resumable(
        self,
        advice: str = "its finished stages would be reused. Choose another --out, or delete the folder to "
        "start over.",
        free: Sequence[str] = (),
    ) -> None:
        """Refuse to continue a run folder whose finished stages were made with another configuration: they
        would be skipped and reported as this configuration's results. A key added to the configuration
        since the folder was made counts as its default, an "auto" precision as the one its runs recorded
        (`records.as_saved_now`); the dotted keys `free` (and the execution keys) may differ."""
        saved = read_saved_config(self.out)
        if saved is None:
            return
        check_same_config(
            as_saved_now(saved, self.out, self.cfg),
            self.cfg,
            ("out", *EXECUTION_KEYS, *free),
            self.out,
            advice,
        )

    def sibling(self, folder: Path, flag: str, free: Sequence[str] = ()) -> Experiment:
        """The experiment in `folder`, refused (UsageError naming `flag` and the differing keys) unless it ran
        this configuration but for its training seeds and arms, the execution keys and the dotted keys `free`
        (the returned experiment's configuration is this one's in those keys)."""
        saved = read_saved_config(folder)
        if saved is None:
            raise UsageError(f"{flag}: {folder} holds no experiment (no {CONFIG_FILE})")
        seeds, arms = tuple(int(s) for s in saved.get("train_seeds", ())), tuple(saved.get("arms", ()))
        other = Experiment(replace(self.cfg, out=folder, train_seeds=seeds, arms=arms), self.preset)
        also = "".join(f", {k}" for k in free)
        other.check_resumable(
            f"{flag} takes folders of the same experiment with other training seeds, arms{also}.", free
        )
        return other

    def run(self, check: bool = True) -> dict[str, Any]:
        """Every stage not finished yet, then the report; `check`: run `preflight` first (the command runs it
        itself before copying `--data-from`)."""
        self.check_resumable()
        if check:
            preflight(self.cfg)
        self.out.mkdir(parents=True, exist_ok=True)
        sweep_stale_temps(self.out)  # what killed writers of an earlier attempt left
        save_config(self.cfg, self.out / CONFIG_FILE)
        results: dict[str, Any] = {}
        for stage in STAGES:
            prev = self.done(stage)
            if prev is not None and stage != "report":
                log.info("stage %s: done earlier, skipping", stage)
                results[stage] = prev
                self.times[stage] = prev.get("seconds", 0.0)
                continue
            log.info("stage %s ...", stage)
            # counts the attempts a kill interrupted too, so a resumed stage reports its whole time
            try:
                with ResumableClock(self.marker(stage).with_suffix(".clock.json")) as clock:
                    res = getattr(self, f"stage_{stage}")(results)
            except (KeyboardInterrupt, Terminated) as e:  # the clock has saved this attempt's time
                annotate_interruption(e, f"stage {stage}", "rerun the same command to resume")
                raise
            self.times[stage] = clock.seconds
            results[stage] = self.finish(stage, res, self.times[stage])
            clock.clear()
        return results

    # ----- stages -------------------------------------------------------------------------------------------
    def stage_demos(self, _: dict[str, Any]) -> dict[str, Any]:
        """Every collection of `demos.demo_collections`; the training demonstrations may be fewer than wanted
        per task (the expert failed on some allowed setup), the others not (`demos.collection_result`); none runs
        `tasks_without_demos`."""
        out, collector = {}, make_collector(self.cfg.env)
        for name, ccfg in demo_collections(self.cfg, self.out).items():
            without = {t: collector.instruction(t) for t in self.cfg.tasks_without_demos if name == "train"}
            out[name] = collection_result(name, collect(ccfg), EpisodeStore(ccfg.out), without)
        return out

    def task_names(self) -> dict[str, str]:
        """Each task as the episode store names its episodes (LIBERO: the task's name in its suite)."""
        collector = make_collector(self.cfg.env)
        return {task: collector.episode_task(task) for task in self.cfg.tasks}

    def priors_needed(self) -> list[PriorSpec]:
        """Every prior the arms train on, and always the gaze source's own: the perturbed controls are made
        from it and the align stage measures every arm against it (a baseline-only experiment too)."""
        names = self.task_names() if self.cfg.glc_folds and "glc" in self.cfg.arms else None
        gaze = gaze_prior(self.cfg)
        needed = {gaze.name: gaze}
        for arm in self.cfg.arms:
            prior = arm_prior(arm, self.cfg, names)
            if prior is not None:
                needed[prior.name] = prior
        return list(needed.values())

    def stage_priors(self, _: dict[str, Any]) -> dict[str, Any]:
        c = self.cfg
        made = []
        glc = None
        if trains_glc(c):  # the glc arm's GLC first: its priors are made with it
            glc = (
                train_glc_folds(c, self.store, self.task_names())
                if c.glc_folds
                else train_glc(c, self.glc_store)
            )
        for store in (self.store, self.heldout):
            for prior in self.priors_needed():
                make_priors(
                    PriorsConfig(
                        store=store,
                        source=prior.source,
                        name=prior.name,
                        camera=c.camera,
                        size=c.prior_size,
                        aggregation=c.aggregation,
                    )
                )
                made.append(f"{store.name}/{prior.name}")
        return {"priors": made, "glc": glc}

    def run_dirs(self) -> dict[RunId, Path]:
        """Every run (arm x training seed) and its training folder."""
        return {
            RunId(arm, seed): run_dir(self.out, RunId(arm, seed))
            for arm in self.cfg.arms
            for seed in self.cfg.train_seeds
        }

    def train_config(self, run: RunId, run_dir: Path) -> TrainConfig:
        c = self.cfg
        prior = arm_prior(run.arm, c)
        prior_name = prior.name if prior is not None else None
        # evenly spaced saves for the convergence curve; the last one is the final step
        every = max(1, math.ceil(c.train.steps / max(1, c.convergence_points)))
        return replace(
            c.train,
            run_dir=run_dir,
            seed=run.seed,
            save_every=every,
            eval_every=min(c.train.eval_every, every),
            progress=True,  # a line per run (gazereg.runtime.progress), from worker processes too
            threads=c.threads_per_run,
            data=replace(c.train.data, store=self.store),
            gaze=replace(
                c.train.gaze,
                prior=prior_name,
                camera=c.camera if prior_name else None,
                target=gaze_target(run.arm),
            ),
        )

    def stage_train(self, _: dict[str, Any]) -> dict[str, Any]:
        jobs = [(run, self.train_config(run, d)) for run, d in self.run_dirs().items()]
        if self.cfg.parallel <= 1:
            finished = [_train_one(cfg) for _, cfg in jobs]
        else:
            ctx = get_context("spawn")
            with ProcessPoolExecutor(self.cfg.parallel, mp_context=ctx, initializer=exit_with_parent) as ex:
                finished = list(ex.map(_train_one, [cfg for _, cfg in jobs]))
        return {"runs": {str(run): res for (run, _), res in zip(jobs, finished)}}

    def final_checkpoints(self, results: dict[str, Any]) -> dict[RunId, str]:
        return {RunId.parse(name): r["checkpoint"] for name, r in results["train"]["runs"].items()}

    def eval_config(self, folder: str, checkpoints: dict[RunId, str], **eval_changes: Any) -> EvalConfig:
        """The evaluation of `checkpoints` (each named by its run) into `out/folder`: the experiment's settings
        on its tasks in its simulator, with `eval_changes`."""
        return replace(
            self.cfg.eval,
            env=self.cfg.env,
            tasks=self.cfg.tasks,
            out=self.out / folder,
            checkpoints=tuple(f"{run}={path}" for run, path in checkpoints.items()),
            **eval_changes,
        )

    def evaluate_checkpoints(
        self, checkpoints: dict[RunId, str], folder: str, **eval_changes: Any
    ) -> dict[str, Any]:
        """Evaluate `checkpoints` (each named by its run) into `out/folder` (`eval_config`)."""
        info = evaluate(self.eval_config(folder, checkpoints, **eval_changes))
        return {"eval_info": str(self.out / folder / EVAL_INFO), "episodes": len(info["episodes"])}

    def stage_eval(self, results: dict[str, Any]) -> dict[str, Any]:
        return self.evaluate_checkpoints(self.final_checkpoints(results), "eval")

    def stage_converge(self, results: dict[str, Any]) -> dict[str, Any]:
        ckpts = {}  # intermediate checkpoints only: the final ones' clean results come from the eval stage
        for run, d in self.run_dirs().items():
            for step, path in list_checkpoints(d):
                if step < self.cfg.train.steps:
                    ckpts[run.at_step(step)] = str(path)
        if not ckpts:
            return {"eval_info": None, "episodes": 0}
        return self.evaluate_checkpoints(
            ckpts,
            "converge",
            conditions=("clean",),
            videos=0,
            episodes=self.cfg.convergence_episodes,
            robustness_episodes=None,
        )

    def stage_align(self, results: dict[str, Any]) -> dict[str, Any]:
        c = self.cfg
        store = EpisodeStore(self.heldout)
        gaze = gaze_prior(c).name
        episodes = store.indices()
        report, maps_by_run = {}, {}
        for run, ckpt in self.final_checkpoints(results).items():
            policy = load_policy(ckpt)
            maps = attention_maps(
                policy, store, episodes, c.camera, gaze, c.train.gaze.layers, queries=c.train.gaze.query_set
            )
            report[str(run)] = alignment_report(maps)
            maps_by_run[run] = (policy, maps)
        figure = self.attention_figure(store, maps_by_run, gaze)
        return {"alignment": report, "figure": figure}

    def attention_figure(self, store: EpisodeStore, maps_by_run: dict[RunId, Any], gaze: str) -> str:
        """Observation | gaze | each arm's attention (first training seed), on frames spread over held-out
        episodes; returns the figure's path relative to the run folder."""
        first: dict[str, Any] = {}
        for run, v in maps_by_run.items():
            first.setdefault(run.arm, v)
        path = self.out / "figures" / "attention.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        plot_attention(*attention_panels(store, first, gaze, self.cfg.camera, self.cfg.figure_frames), path)
        return str(path.relative_to(self.out))

    def stage_report(self, _: dict[str, Any]) -> dict[str, Any]:
        """report.json, report.md and the figures, from the finished stages' records as `read_run` reads
        them (so a report rebuilt later from the folder, or from its archive, is this one)."""
        outputs = read_run(self.out).stage_outputs()
        report = build_report(report_spec(self.cfg, self.preset), outputs, self.out)
        return {"report": str(write_report(self.out, report))}


def _train_one(cfg: TrainConfig) -> dict[str, Any]:
    """Train one run to completion, resuming from its newest checkpoint if it has one."""
    logging.basicConfig(level=logging.WARNING)
    done = [s for s, _ in list_checkpoints(cfg.run_dir) if s >= cfg.steps]
    if done:
        return {"checkpoint": str(latest_checkpoint(cfg.run_dir)), "step": done[-1], "resumed": False}
    resume = latest_checkpoint(cfg.run_dir) is not None
    res = train(replace(cfg, resume=resume))
    return {
        "checkpoint": str(res["checkpoint"]),
        "step": int(res["step"]),
        "resumed": resume,
        "final_metrics": res["metrics"],
    }
