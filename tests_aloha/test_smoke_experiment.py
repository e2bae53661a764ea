"""The `aloha` preset's pipeline at toy size, end to end in Gym-Aloha: two expert demonstrations per task with their
gaze extras (two, so that the same_task control has another demonstration of the task to take its gaze from),
visuomotor priors and their controls, a few training steps per arm (a toy policy executing actions as the
preset's does), one evaluation episode per task (of 400 steps)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np

from gazereg.data.store import EpisodeStore
from gazereg.evaluation.config import EvalConfig
from gazereg.experiment.config_sims import aloha
from gazereg.experiment.demos import demo_stores
from gazereg.experiment.runner import Experiment
from gazereg.gaze.sources.visuomotor import VisuomotorGaze
from gazereg.training.config import GazeConfig
from gazereg.training.config import ci as ci_train


def test_the_aloha_pipeline_runs_every_stage(tmp_path):
    base, toy = aloha(), ci_train()
    chunking = {k: getattr(base.train.policy, k) for k in ("chunk", "n_action_steps", "temporal_ensemble")}
    cfg = replace(
        base,
        out=tmp_path / "exp",
        image_size=48,
        demos_per_task=2,
        demo_max_failures=0,
        heldout_per_task=2,
        collect_workers=1,
        prior_size=(32, 32),
        train=replace(toy, steps=4, gaze=GazeConfig(weight=0.1), policy=replace(toy.policy, **chunking)),
        parallel=1,
        eval=replace(
            base.eval, episodes=1, robustness_episodes=None, workers=1, videos=0, conditions=("clean",)
        ),
        convergence_episodes=1,
        figure_frames=2,
    )
    assert isinstance(cfg.eval, EvalConfig) and cfg.eval.max_steps == 400
    Experiment(cfg, "aloha").run()
    report = json.loads((cfg.out / "report.json").read_text())
    assert (
        set(report["success"]) == set(base.arms) >= {"baseline", "gaze", "same_task", "perturbed", "uniform"}
    )
    for arm in report["success"].values():
        assert arm["clean"]["n"] == 2  # one episode per task
    store = EpisodeStore(demo_stores(cfg.out)["train"])
    episodes = list(store)
    assert sorted(ep.task for ep in episodes) == sorted(cfg.tasks * cfg.demos_per_task)
    for ep in episodes:
        assert ep.meta["success"], ep.task  # the expert's demonstration of this setup succeeded
        trace = VisuomotorGaze().trace(ep, "top")
        assert trace.targets == tuple(ep.meta["gaze_targets"])
        assert trace.arrivals[0] == int(np.argmax(ep.extras["contact.obj"]))
        assert trace.valid.mean() > 0.9  # the gaze stays in the image
