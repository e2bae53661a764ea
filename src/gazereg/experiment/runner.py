"""`gazereg experiment`: the whole pipeline, stage by stage, resumable (the README's main job).

    gazereg experiment --preset quick            # make demo: a few Meta-World tasks, ~15 min on 2 CPU cores
    gazereg experiment --preset smoke            # CI: the same code, tiny sizes
    gazereg experiment --preset paper            # powered: 3 arms x 3 training seeds, 50 episodes per task and condition
    gazereg experiment --preset full             # every ablation arm, 5 tasks, 128 px: for a many-core GPU machine

Stages (each writes into `out/` and a marker `out/stages/<name>.json`; a rerun skips finished stages, so a
killed run loses at most the stage it was in; training resumes from its last checkpoint and evaluation
from its episode log, episodes.jsonl):
  demos      scripted experts on training setups (seeds 0..demos_per_task-1) + held-out setups for alignment
  priors     one prior per gaze source an arm needs (the gaze source, and its perturbed controls)
  train      every arm x training seed with the same budget; arms differ only in their gaze prior
  eval       final checkpoints on shared unseen setups, clean and perturbed (lighting, sensor noise)
  converge   intermediate checkpoints, clean, for success-versus-steps curves
  align      attention vs gaze on held-out frames; the attention figure
  report     report.json, report.md, figures
Arms: baseline (no gaze term), gaze (the gaze source), perturbed (its patches shuffled), blobs (random
blobs), other_episode (another episode's gaze), saliency, uniform, glc.
"""

from __future__ import annotations

import json
import logging
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from datetime import datetime, timezone
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from gazereg.evaluation.rollout import evaluate
from gazereg.experiment.config import (
    EXECUTION_KEYS,
    PRESETS,
    ExperimentConfig,
    arm_prior,
    glc_dir,
    trains_glc,
)
from gazereg.report.tables import base_arm
from gazereg.runtime.clock import ResumableClock
from gazereg.runtime.config import config_diff, save_config, to_dict
from gazereg.runtime.io import atomic_write_json, atomic_write_text
from gazereg.training.config import TrainConfig

log = logging.getLogger(__name__)


class ConfigMismatch(ValueError):
    """The run folder holds stages made with another configuration (see `Experiment.check_resumable`)."""


STAGES = ("demos", "priors", "train", "eval", "converge", "align", "report")


class Experiment:
    def __init__(self, cfg: ExperimentConfig, preset: str = "custom"):
        self.cfg, self.preset = cfg, preset
        self.out = Path(cfg.out)
        self.store = self.out / "demos"
        self.heldout = self.out / "heldout"
        self.glc_store = self.out / "glc_demos"
        self.times: dict[str, float] = {}

    # ----- bookkeeping ------------------------------------------------------------------------------------
    def marker(self, stage: str) -> Path:
        return self.out / "stages" / f"{stage}.json"

    def done(self, stage: str) -> dict[str, Any] | None:
        m = self.marker(stage)
        return json.loads(m.read_text()) if m.exists() else None

    def finish(self, stage: str, result: dict[str, Any], seconds: float) -> dict[str, Any]:
        atomic_write_json(self.marker(stage), {**result, "seconds": seconds})
        return result

    def check_resumable(self) -> None:
        """Refuse to continue a run folder whose finished stages were made with another configuration: they
        would be skipped and reported as this configuration's results."""
        saved = self.out / "config.json"
        if not saved.exists():
            return
        ignore = ("out", *EXECUTION_KEYS)
        diff = config_diff(json.loads(saved.read_text()), json.loads(json.dumps(to_dict(self.cfg))), ignore)
        if diff:
            changes = ", ".join(f"{k}: {a!r} -> {b!r}" for k, (a, b) in diff.items())
            raise ConfigMismatch(
                f"{self.out} holds a run with another configuration ({changes}); its finished stages would be "
                "reused. Choose another --out, or delete the folder to start over."
            )

    def run(self) -> dict[str, Any]:
        self.check_resumable()
        self.out.mkdir(parents=True, exist_ok=True)
        save_config(self.cfg, self.out / "config.json")
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
            with ResumableClock(self.out / "stages" / f"{stage}.clock.json") as clock:
                res = getattr(self, f"stage_{stage}")(results)
            self.times[stage] = clock.seconds
            results[stage] = self.finish(stage, res, self.times[stage])
            clock.clear()
        return results

    # ----- stages -------------------------------------------------------------------------------------------
    def stage_demos(self, _: dict[str, Any]) -> dict[str, Any]:
        from gazereg.data.store import EpisodeStore
        from gazereg.envs.collect import CollectConfig, collect

        c = self.cfg
        common = dict(
            tasks=c.tasks,
            cameras=(c.camera,),
            image_size=c.image_size,
            workers=c.collect_workers,
            gl_backend=c.eval.gl_backend or "",
        )
        out = {}
        sets = [
            ("train", self.store, c.demos_per_task, 0),
            ("heldout", self.heldout, c.heldout_per_task, c.eval.seed_start + 500),
        ]
        if trains_glc(c):
            sets.append(("glc", self.glc_store, c.glc_demos_per_task, c.eval.seed_start + 700))
        for name, store, n, seed_base in sets:
            report = collect(CollectConfig(out=store, episodes=n, seed_base=seed_base, **common))
            if not report.complete:
                raise RuntimeError(
                    f"demo collection into {store} did not reach {n} successful episodes per task: {report.tasks}"
                )
            st = EpisodeStore(store)
            out[name] = {
                "episodes": len(st),
                "frames": sum(st.meta(i)["length"] for i in st.indices()),
                "seconds": report.seconds,
            }
        return out

    def priors_needed(self) -> list[tuple[str, str, tuple[str, ...]]]:
        """(prior name, gaze source, params) of every prior the arms train on, and always the gaze source's
        own: the perturbed controls are made from it and the align stage measures every arm against it (a
        baseline-only experiment too)."""
        base, bsrc, bparams = arm_prior("gaze", self.cfg)
        assert base is not None and bsrc is not None
        needed: dict[str, tuple[str, str, tuple[str, ...]]] = {base: (base, bsrc, bparams)}
        for arm in self.cfg.arms:
            name, source, params = arm_prior(arm, self.cfg)
            if name is not None and source is not None:
                needed[name] = (name, source, params)
        return list(needed.values())

    def stage_priors(self, _: dict[str, Any]) -> dict[str, Any]:
        from gazereg.gaze.priors import PriorsConfig, make_priors

        c = self.cfg
        made = []
        glc = self.train_glc() if trains_glc(c) else None
        for store in (self.store, self.heldout):
            for name, source, params in self.priors_needed():
                make_priors(
                    PriorsConfig(
                        store=store,
                        source=source,
                        source_params=params,
                        name=name,
                        camera=c.camera,
                        size=c.prior_size,
                        aggregation=c.aggregation,
                    )
                )
                made.append(f"{store.name}/{name}")
        return {"priors": made, "glc": glc}

    def train_glc(self) -> dict[str, Any]:
        """Train the small GLC on the gaze source's points of the GLC demonstrations (resumes; every 5th
        episode per task held out for its F1/AUC against a centre prior), for the glc arm's priors."""
        from gazereg.gaze.glc.cli import GLCTrainCommand, train_command

        c = self.cfg
        base = GLCTrainCommand()
        info = train_command(
            replace(
                base,
                store=self.glc_store,
                camera=c.camera,
                gaze_source=c.gaze_source,
                gaze_params=c.gaze_params,
                out=glc_dir(c),
                optim=replace(base.optim, steps=c.glc_steps),
            )
        )
        out: dict[str, Any] = {"checkpoint": str(glc_dir(c) / "final"), "steps": info["steps"], "eval": None}
        if info.get("eval"):
            rep = json.loads(Path(info["eval"]).read_text())
            out["eval"] = {
                "heldout": rep["episodes"],
                **{
                    f"{name}_{metric}": rep["scores"]["all_valid"][name][metric]
                    for name in ("glc", "centre_prior", "uniform")
                    for metric in ("f1", "auc")
                },
            }
        return out

    def run_dirs(self) -> dict[str, Path]:
        return {
            f"{arm}@s{seed}": self.out / "train" / f"{arm}_s{seed}"
            for arm in self.cfg.arms
            for seed in self.cfg.train_seeds
        }

    def train_config(self, arm: str, seed: int, run_dir: Path) -> TrainConfig:
        c = self.cfg
        prior, _, _ = arm_prior(arm, c)
        every = max(
            1, math.ceil(c.train.steps / max(1, c.convergence_points))
        )  # the last save is the final step
        return replace(
            c.train,
            run_dir=run_dir,
            seed=seed,
            save_every=every,
            eval_every=min(c.train.eval_every, every),
            progress=False,
            threads=c.threads_per_run,
            data=replace(c.train.data, store=self.store),
            gaze=replace(c.train.gaze, prior=prior, camera=c.camera if prior else None),
        )

    def stage_train(self, _: dict[str, Any]) -> dict[str, Any]:
        jobs = [
            (name, self.train_config(name.split("@")[0], int(name.split("@s")[1]), d))
            for name, d in self.run_dirs().items()
        ]
        if self.cfg.parallel <= 1:
            finished = [_train_one(cfg) for _, cfg in jobs]
        else:
            with ProcessPoolExecutor(self.cfg.parallel, mp_context=get_context("spawn")) as ex:
                finished = list(ex.map(_train_one, [cfg for _, cfg in jobs]))
        return {"runs": {name: res for (name, _), res in zip(jobs, finished)}}

    def final_checkpoints(self, results: dict[str, Any]) -> dict[str, str]:
        return {name: r["checkpoint"] for name, r in results["train"]["runs"].items()}

    def stage_eval(self, results: dict[str, Any]) -> dict[str, Any]:
        ckpts = self.final_checkpoints(results)
        ecfg = replace(
            self.cfg.eval,
            tasks=self.cfg.tasks,
            out=self.out / "eval",
            checkpoints=tuple(f"{k}={v}" for k, v in ckpts.items()),
        )
        info = evaluate(ecfg)
        return {"eval_info": str(self.out / "eval" / "eval_info.json"), "episodes": len(info["episodes"])}

    def stage_converge(self, results: dict[str, Any]) -> dict[str, Any]:
        from gazereg.training.checkpoint import list_checkpoints

        ckpts = {}  # intermediate checkpoints only: the final ones' clean results come from the eval stage
        for name, d in self.run_dirs().items():
            for step, path in list_checkpoints(d):
                if step < self.cfg.train.steps:
                    ckpts[f"{name}#{step}"] = str(path)
        if not ckpts:
            return {"eval_info": None, "episodes": 0}
        ecfg = replace(
            self.cfg.eval,
            tasks=self.cfg.tasks,
            out=self.out / "converge",
            conditions=("clean",),
            videos=0,
            episodes=self.cfg.convergence_episodes,
            checkpoints=tuple(f"{k}={v}" for k, v in ckpts.items()),
        )
        info = evaluate(ecfg)
        return {"eval_info": str(self.out / "converge" / "eval_info.json"), "episodes": len(info["episodes"])}

    def stage_align(self, results: dict[str, Any]) -> dict[str, Any]:
        from gazereg.data.store import EpisodeStore
        from gazereg.evaluation.alignment import alignment_report, attention_maps
        from gazereg.policies import load_policy

        c = self.cfg
        store = EpisodeStore(self.heldout)
        gaze_prior, _, _ = arm_prior("gaze", c)
        episodes = store.indices()
        report, maps_by_arm = {}, {}
        for name, ckpt in self.final_checkpoints(results).items():
            policy = load_policy(ckpt)
            layers = c.train.gaze.layers
            maps = attention_maps(policy, store, episodes, c.camera, gaze_prior, layers)
            report[name] = alignment_report(maps)
            maps_by_arm[name] = (policy, maps)
        figure = self.attention_figure(store, maps_by_arm, gaze_prior)
        return {"alignment": report, "figure": figure}

    def attention_figure(self, store: Any, maps_by_arm: dict[str, Any], gaze_prior: str | None) -> str:
        """Observation | gaze | each arm's attention (first training seed), on frames spread over held-out episodes."""
        import numpy as np

        from gazereg.patches import grid_to_image
        from gazereg.report import plot_attention

        c = self.cfg
        first: dict[str, Any] = {}
        for name, v in maps_by_arm.items():
            first.setdefault(name.split("@")[0], v)
        any_maps = next(iter(first.values()))[1]
        ep_t = any_maps["episode_t"].numpy()
        rows = np.linspace(0, len(ep_t) - 1, c.figure_frames + 2).round().astype(int)[1:-1]
        panels = []
        for r in rows:
            ep, t = int(ep_t[r, 0]), int(ep_t[r, 1])
            episode = store.read(ep, cameras=[c.camera])
            frame = np.asarray(episode.frames[c.camera][t])
            panel: dict[str, Any] = {"title": f"{episode.task} t={t}", "frame": frame}
            if gaze_prior:
                heat, _ = store.read_prior(gaze_prior, ep)
                panel["gaze prior"] = heat[t]
            for arm, (policy, maps) in first.items():
                panel[f"{arm} attention"] = grid_to_image(
                    maps["attention"][r], policy.geometry(c.camera), frame.shape[:2]
                ).numpy()
            panels.append(panel)
        columns = (["gaze prior"] if gaze_prior else []) + [f"{arm} attention" for arm in first]
        path = self.out / "figures" / "attention.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        plot_attention(panels, columns, path)
        return str(path.relative_to(self.out))

    def results_date(self) -> str:
        """When the results were produced: the last stage before the report finished (a rerun that only
        rewrites the report keeps that date)."""
        times = [self.marker(s).stat().st_mtime for s in STAGES[:-1] if self.marker(s).exists()]
        when = datetime.fromtimestamp(max(times), timezone.utc) if times else datetime.now(timezone.utc)
        return when.strftime("%Y-%m-%d %H:%M UTC")

    def stage_report(self, results: dict[str, Any]) -> dict[str, Any]:
        from gazereg.report import (
            convergence,
            distance_table,
            machine_summary,
            markdown,
            paired_distance_tests,
            paired_tests,
            per_seed_table,
            plot_convergence,
            plot_success,
            success_table,
            verdict,
        )
        from gazereg.training.logger import read_metrics

        c = self.cfg
        ev = json.loads(Path(results["eval"]["eval_info"]).read_text())
        success = success_table(ev["episodes"])
        # Each arm against the baseline, and the gaze arm against its own perturbed-gaze control.
        control = _gaze_and_control(ev["episodes"], c.arms)
        paired = {**paired_tests(ev["episodes"]), **paired_tests(control, "perturbed")}
        conv_path = results["converge"]["eval_info"]
        conv_records = json.loads(Path(conv_path).read_text())["episodes"] if conv_path else []
        last_seed = c.eval.seed_start + min(c.convergence_episodes, c.eval.episodes)
        final_clean = [
            {**r, "arm": f"{r['arm']}#{c.train.steps}"}
            for r in ev["episodes"]
            if r["condition"] == "clean" and r["seed"] < last_seed
        ]
        curves: dict[str, dict[int, list[int]]] = {}
        for r in conv_records + final_clean:
            name, step = r["arm"].rsplit("#", 1)
            cell = curves.setdefault(name.split("@")[0], {}).setdefault(int(step), [0, 0])
            cell[0] += int(r["success"])
            cell[1] += 1
        conv = convergence(
            {a: {s: (k, n) for s, (k, n) in pts.items()} for a, pts in curves.items()}, c.threshold
        )
        losses = {}
        for name, d in self.run_dirs().items():
            if name.endswith(f"@s{c.train_seeds[0]}"):
                recs = read_metrics(d / "metrics.jsonl")
                losses[name.split("@")[0]] = [
                    (r["step"], r["loss/action"], r.get("val/gaze_kl")) for r in recs if "loss/action" in r
                ]
        figs = self.out / "figures"
        figs.mkdir(parents=True, exist_ok=True)
        plot_success(success, figs / "success.png")
        plot_convergence(conv, losses, figs / "convergence.png")
        demos = results["demos"]["train"]
        report = {
            "preset": self.preset,
            "date": self.results_date(),
            "machine": machine_summary(),
            "wall_time_s": sum(self.times.values()),
            "stage_times_s": dict(self.times),
            "tasks": list(c.tasks),
            "demos": {"episodes": demos.get("episodes"), "frames": demos.get("frames")},
            "train": {
                "steps": c.train.steps,
                "batch_size": c.train.batch_size,
                "seeds": list(c.train_seeds),
                "gaze_weight": c.train.gaze.weight,
                "gaze_layers": list(c.train.gaze.layers),
                "arms": list(c.arms),
            },
            "eval": {
                "episodes": c.eval.episodes,
                "conditions": list(c.eval.conditions),
                "seeds": f"{c.eval.seed_start}..{c.eval.seed_start + c.eval.episodes - 1}",
            },
            "success": success,
            "paired": paired,
            "per_seed": per_seed_table(ev["episodes"]) if len(c.train_seeds) > 1 else None,
            "distance": {
                "table": distance_table(ev["episodes"]),
                "paired": {
                    **paired_distance_tests(ev["episodes"]),
                    **paired_distance_tests(control, reference="perturbed"),
                },
            },
            "verdict": verdict(success, paired=paired)
            + (verdict(success_table(control), "perturbed", paired) if control else []),
            "convergence": conv,
            "glc": results["priors"].get("glc"),
            "val_loss": {
                name: r.get("final_metrics", {}).get("val/loss_action")
                for name, r in results["train"]["runs"].items()
            },
            "alignment": {
                n.split("@")[0] if len(c.train_seeds) == 1 else n: v
                for n, v in results["align"]["alignment"].items()
            },
            "figures": {
                "success": "figures/success.png",
                "convergence": "figures/convergence.png",
                "attention": results["align"]["figure"],
            },
            "videos": [str(Path(e["video"]).relative_to(self.out)) for e in ev["episodes"] if e.get("video")],
            "config": to_dict(c),
        }
        atomic_write_json(self.out / "report.json", report)
        atomic_write_text(self.out / "report.md", markdown(report))
        return {"report": str(self.out / "report.md")}


def _gaze_and_control(records: list[dict[str, Any]], arms: tuple[str, ...]) -> list[dict[str, Any]]:
    """The episodes of the gaze arm and its perturbed-gaze control, the report's second reference (every arm
    is also compared with the baseline); empty when the run lacks either arm."""
    if not {"gaze", "perturbed"} <= set(arms):
        return []
    return [r for r in records if base_arm(r["arm"]) in ("gaze", "perturbed")]


def _train_one(cfg: TrainConfig) -> dict[str, Any]:
    """Train one run to completion, resuming from its newest checkpoint if it has one."""
    from gazereg.training.checkpoint import latest_checkpoint, list_checkpoints
    from gazereg.training.loop import train

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


def main(argv: list[str] | None = None) -> int:
    from gazereg.runtime.config import parse, split_preset

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    args = sys.argv[1:] if argv is None else argv
    preset, _ = split_preset(args, "quick")
    cfg = parse(PRESETS, args, prog="gazereg experiment", description=__doc__ or "")
    t0 = time.perf_counter()
    try:
        Experiment(cfg, preset).run()
    except ConfigMismatch as e:
        print(f"gazereg experiment: {e}", file=sys.stderr)
        return 2
    print((Path(cfg.out) / "report.md").read_text())
    print(
        f"experiment finished in {(time.perf_counter() - t0) / 60:.1f} min; report: {Path(cfg.out) / 'report.md'}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
