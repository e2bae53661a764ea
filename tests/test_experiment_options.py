"""The experiment's options for LIBERO (issue #22): the simulator, demonstrations that stay off the evaluation's
setups, cross-fitted GLC folds, fewer setups under the perturbed conditions, and old run folders that still
resume. No simulator needed (LIBERO's own parts: tests/envs/test_libero_experiment.py)."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import pytest

from gazereg.envs.collect_config import collect_seeds
from gazereg.evaluation.config import EvalConfig
from gazereg.experiment.arms import arm_prior, fold_tasks, glc_fold_dir
from gazereg.experiment.config import PRESETS, paper, quick, smoke
from gazereg.experiment.config_sims import libero, libero_smoke
from gazereg.experiment.demos import demo_collections
from gazereg.experiment.finished import recorded_precision
from gazereg.experiment.runner import Experiment
from gazereg.gaze.sources.glc_folds import GLCFoldsParams
from gazereg.runtime.config import ConfigMismatch, to_dict
from gazereg.runtime.errors import UsageError
from gazereg.training.numerics import record_numerics


def _saved_without(cfg, path: Path, *keys: str) -> None:
    """Save `cfg` as config.json in `path` as a run made before `keys` (dotted) existed would have."""
    d = to_dict(cfg)
    for key in keys:
        *parents, leaf = key.split(".")
        node = d
        for p in parents:
            node = node[p]
        del node[leaf]
    path.mkdir(parents=True, exist_ok=True)
    (path / "config.json").write_text(json.dumps(d))


ADDED = ("env", "demo_max_failures", "glc_folds", "eval.robustness_episodes", "tasks_without_demos")


@pytest.mark.parametrize("preset", [quick, paper, smoke])
def test_a_run_folder_made_before_the_new_keys_resumes_while_they_keep_their_defaults(tmp_path, preset):
    cfg = replace(preset(), out=tmp_path / "run")
    _saved_without(cfg, cfg.out, *ADDED)
    Experiment(cfg).check_resumable()  # the new keys at their defaults: the same run
    with pytest.raises(ConfigMismatch, match="demo_max_failures: 20 -> 0"):
        Experiment(replace(cfg, demo_max_failures=0)).check_resumable()
    with pytest.raises(ConfigMismatch, match="eval.robustness_episodes: None -> 1"):
        Experiment(replace(cfg, eval=replace(cfg.eval, robustness_episodes=1))).check_resumable()


def _trained_in(folder: Path, arm_precisions: dict[str, str | None]) -> None:
    """Record each run's training in `folder` as this machine's, in its precision (None: a run made before
    runs recorded their numerics: a folder without numerics.json)."""
    for run, precision in arm_precisions.items():
        (folder / "train" / run).mkdir(parents=True, exist_ok=True)
        if precision is not None:
            record_numerics(folder / "train" / run, precision, start=0)


def test_a_folder_saved_with_auto_precision_is_the_pinned_precision_its_runs_trained_in(tmp_path):
    auto = replace(quick(), out=tmp_path / "run")
    auto = replace(auto, train=replace(auto.train, mixed_precision="auto"))
    pinned = replace(auto, train=replace(auto.train, mixed_precision="no"))
    _saved_without(auto, auto.out)
    _trained_in(auto.out, {"baseline_s0": "no", "gaze_s0": "no"})
    assert recorded_precision(auto.out) == "no"
    Experiment(pinned).check_resumable()  # "auto" that trained in float32 everywhere is float32
    Experiment(auto).check_resumable()  # and still itself
    bf16 = replace(auto, train=replace(auto.train, mixed_precision="bf16"))
    with pytest.raises(ConfigMismatch, match="train.mixed_precision: 'auto' -> 'bf16'"):
        Experiment(bf16).check_resumable()
    record_numerics(auto.out / "train" / "gaze_s0", "bf16", start=10)  # resumed where auto is bf16
    assert recorded_precision(auto.out) is None
    with pytest.raises(ConfigMismatch, match="train.mixed_precision: 'auto' -> 'no'"):
        Experiment(pinned).check_resumable()


@pytest.mark.parametrize("runs", [{}, {"baseline_s0": "no", "gaze_s0": None}, {"a_s0": "no", "b_s0": "bf16"}])
def test_no_single_recorded_precision_leaves_auto_unresolved(tmp_path, runs):
    _trained_in(tmp_path, runs)
    assert recorded_precision(tmp_path) is None


def test_the_existing_presets_keep_their_settings():
    for preset in (quick, smoke, paper):
        cfg = preset()
        assert cfg.env == "metaworld" and cfg.eval.env == "metaworld"
        assert cfg.demo_max_failures == 20 and cfg.glc_folds == () and cfg.eval.robustness_episodes is None
        train = demo_collections(cfg, Path("x"))["train"]
        assert (train.seed_base, train.episodes, train.max_failures) == (0, cfg.demos_per_task, 20)


def test_libero_training_demos_and_evaluation_use_disjoint_setup_seeds():
    """Per task, the seeds the training collection may roll out (its configuration as the demos stage builds
    it, read by the collection's own `collect_seeds`) and every condition's evaluation seeds (the evaluation
    configuration as the eval stage builds it) do not meet. Initial states: tests/envs/test_libero_experiment.py."""
    for cfg in (libero(), libero_smoke()):
        exp = Experiment(cfg)
        train = demo_collections(cfg, exp.out)["train"]
        assert train.env == "libero" and train.tasks == cfg.tasks
        demo_seeds = set(collect_seeds(train))
        ecfg = exp.eval_config("eval", {})
        assert ecfg.env == "libero" and ecfg.tasks == cfg.tasks
        for condition in ecfg.conditions:
            eval_seeds = set(ecfg.seeds(condition))
            assert eval_seeds and not demo_seeds & eval_seeds, condition
        assert max(demo_seeds) < min(ecfg.seeds("clean"))


def test_the_libero_preset():
    cfg = libero()
    assert len(cfg.tasks) == 10 and cfg.camera == "agentview_rgb" and cfg.image_size == 128
    assert cfg.train.policy.image_hw == (128, 128) and cfg.train.policy.patch_size == 16
    assert cfg.arms == ("baseline", "gaze", "glc", "uniform", "perturbed") and cfg.train_seeds == (0,)
    assert cfg.eval.conditions == ("clean", "dim:0.7", "gaussian_noise:0.5") and cfg.eval.max_steps == 220
    assert (
        len(cfg.eval.seeds("clean")) == 25 and len(cfg.eval.seeds("dim:0.7")) == cfg.eval.robustness_episodes
    )
    assert cfg.convergence_points == 1
    assert "glc" not in demo_collections(cfg, Path("x"))  # the folds train on the training demos
    for preset in ("libero", "libero_smoke"):
        assert PRESETS[preset]().env == "libero"


def test_libero_10_evaluates_every_task_and_trains_on_those_its_expert_demonstrates():
    """The preset's tasks without demonstrations are exactly those its expert never solved in its measured record
    (docs/benchmarks/libero_10_expert.json); no collection runs them, the evaluation runs all ten."""
    cfg = PRESETS["libero_10"]()
    record = json.loads((Path(__file__).parents[1] / "docs/benchmarks/libero_10_expert.json").read_text())
    never = tuple(r["task"] for r in record["tasks"].values() if r["successes"] == 0)
    assert never and cfg.tasks_without_demos == never
    assert cfg.demo_tasks == tuple(t for t in cfg.tasks if t not in never) and len(cfg.demo_tasks) == 9
    for name, collection in demo_collections(cfg, Path("x")).items():
        assert collection.tasks == cfg.demo_tasks, name
    assert Experiment(cfg).eval_config("eval", {}).tasks == cfg.tasks and len(cfg.tasks) == 10


def test_the_demos_record_counts_a_task_without_demonstrations_apart():
    from gazereg.envs.collect import CollectReport
    from gazereg.experiment.demos import collection_result
    from gazereg.report.sections import demos_text

    class Store:  # the two episode-store reads collection_result makes
        metas = [
            {"task": "t", "env_name": f"s/{k // 2}", "instruction": f"do {k // 2}", "length": 10}
            for k in range(3)
        ]

        def indices(self):
            return range(len(self.metas))

        def meta(self, i):
            return self.metas[i]

    tasks = {"s/0": {"episodes": 2, "wanted": 2}, "s/1": {"episodes": 1, "wanted": 2}}
    report = CollectReport(tasks=tasks, seconds=1.0, new_episodes=3, new_frames=30, complete=False)
    got = collection_result("train", report, Store(), {"s/2": "do 2"})
    assert got["per_task"] == {"s/0": 2, "s/1": 1, "s/2": 0} and got["without"] == ["s/2"]
    assert got["instructions"] == {"s/0": "do 0", "s/1": "do 1", "s/2": "do 2"}
    assert demos_text(got) == (
        "3 episodes (30 frames) on training setups, 2 per task but fewer where the expert failed (s/1 1); "
        "none of s/2 (the expert cannot demonstrate it: evaluated, never trained on)"
    )
    assert "none of" not in demos_text(collection_result("train", report, Store()))


def test_a_glc_fold_trains_and_scores_on_its_tasks_with_demonstrations_only(tmp_path, monkeypatch):
    from gazereg.experiment import glc

    calls = []
    monkeypatch.setattr(glc, "_run", lambda cfg, store, out, **kw: calls.append(kw))
    monkeypatch.setattr(glc, "_record", lambda trained: {})
    cfg = replace(PRESETS["libero_10"](), out=tmp_path)
    folds = glc.train_glc_folds(cfg, tmp_path, {t: t for t in cfg.tasks})["folds"]
    assert [f["predicts"] for f in folds] == [list(cfg.tasks[:5]), list(cfg.tasks[5:9])]
    assert calls[1] == {"tasks": cfg.tasks[:5], "heldout_tasks": cfg.tasks[5:9]}
    assert calls[0]["tasks"] == cfg.tasks[5:9]


def test_each_tasks_glc_prior_comes_from_the_fold_that_did_not_train_on_it(tmp_path):
    cfg = replace(libero(), out=tmp_path)
    names = {t: f"name of {t}" for t in cfg.tasks}
    source = arm_prior("glc", cfg, names).source
    assert isinstance(source, GLCFoldsParams) and set(source.tasks) == set(names.values())
    for k in range(len(cfg.glc_folds)):
        trained_on, predicts = fold_tasks(cfg, k)
        assert predicts == cfg.glc_folds[k] and not set(trained_on) & set(predicts)
        assert set(trained_on) | set(predicts) == set(cfg.tasks)
        for task in predicts:
            assert source.checkpoints[source.tasks.index(names[task])] == glc_fold_dir(cfg, k) / "final"
    assert (source.stride, source.mode, source.hop) == (cfg.glc.stride, cfg.glc.mode, cfg.glc.hop)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"glc_folds": (("libero_spatial/0",),)}, "--glc-folds takes at least two non-empty groups"),
        (
            {"glc_folds": (("libero_spatial/0",), ("libero_spatial/1", "libero_spatial/0"))},
            "--glc-folds lists libero_spatial/0 more than once",
        ),
        ({"glc_folds": (("libero_spatial/0",), ("libero_spatial/7",))}, "in no group: ['libero_spatial/1']"),
        ({"glc_folds": (("libero_spatial/0",), ("libero_spatial/1", "x"))}, "not tasks: ['x']"),
        ({"demo_max_failures": -1}, "--demo-max-failures must be an integer >= 0"),
        (
            {"tasks_without_demos": ("libero_spatial/7",)},
            "--tasks-without-demos: ['libero_spatial/7'] are not in",
        ),
        (
            {"tasks_without_demos": ("libero_spatial/0", "libero_spatial/1")},
            "--tasks-without-demos names every task: nothing would be trained on",
        ),
        (
            {"tasks_without_demos": ("libero_spatial/1",)},
            "the glc fold ['libero_spatial/1'] has no task with demonstrations",
        ),
        ({"env": "metaworld"}, "--eval.env libero differs from --env metaworld"),
    ],
)
def test_bad_libero_options_are_refused_naming_them(changes, message):
    with pytest.raises(UsageError) as refused:
        replace(libero_smoke(), **changes)
    assert message in str(refused.value)


def test_folds_and_a_given_glc_checkpoint_are_refused_together(tmp_path):
    cfg = libero_smoke()
    with pytest.raises(UsageError, match="--glc-folds trains a GLC per group; --glc.checkpoint gives one"):
        replace(cfg, glc=replace(cfg.glc, checkpoint=tmp_path))


def test_fewer_setups_under_the_perturbed_conditions_are_a_prefix_of_the_clean_ones():
    from gazereg.evaluation.rollout import make_jobs

    cfg = EvalConfig(
        episodes=4, robustness_episodes=2, seed_start=10, conditions=("clean", "dim:0.7"), videos=0
    )
    assert list(cfg.seeds("clean")) == [10, 11, 12, 13] and list(cfg.seeds("dim:0.7")) == [10, 11]
    jobs = make_jobs(cfg, {"a": Path("a"), "b": Path("b")})
    by: dict[tuple[str, str], list[int]] = {}
    for j in jobs:
        by.setdefault((j.arm, j.condition), []).append(j.seed)
    assert by[("a", "dim:0.7")] == by[("b", "dim:0.7")] == [10, 11] and by[("a", "clean")] == [10, 11, 12, 13]
    assert list(EvalConfig(episodes=3).seeds("dim:0.7")) == [1000, 1001, 1002]
    with pytest.raises(UsageError, match=r"--robustness-episodes must be an integer in \[1, 4\], got 5"):
        replace(cfg, robustness_episodes=5)


def test_drop_from_clean_is_measured_on_the_perturbed_conditions_setups():
    from gazereg.evaluation.summary import summarize
    from gazereg.report.tables import paired_tests, success_table

    def rec(arm, cond, seed, ok):
        return {"arm": f"{arm}@s0", "task": "t", "condition": cond, "seed": seed, "success": ok, "length": 5}

    records = [rec(a, "clean", s, s < 2) for a in ("baseline", "gaze") for s in range(4)]
    records += [rec(a, "dim:0.7", s, a == "gaze") for a in ("baseline", "gaze") for s in range(2)]
    table = success_table(records)
    assert table["baseline"]["clean"]["rate"] == 0.5 and table["baseline"]["dim:0.7"]["n"] == 2
    # clean on setups 0 and 1 (both solved) against dim on the same setups
    assert (
        table["baseline"]["dim:0.7"]["drop_from_clean"] == 1.0
        and table["gaze"]["dim:0.7"]["drop_from_clean"] == 0.0
    )
    assert table["baseline"]["clean"]["drop_from_clean"] == 0.0
    assert summarize(records)["arms"]["baseline@s0"]["dim:0.7"]["drop_from_clean"] == 1.0
    paired = paired_tests(records)
    assert (
        paired["gaze vs baseline | dim:0.7"]["pairs"] == 2
        and paired["gaze vs baseline | clean"]["pairs"] == 4
    )


def test_the_report_of_ten_tasks_four_arms_folds_and_fewer_demos():
    import copy

    from gazereg.report import markdown

    golden = Path(__file__).parent / "report_golden" / "smoke_report.json"
    report = json.loads(golden.read_text())
    tasks = [f"libero_spatial/{k}" for k in range(10)]
    for arm in report["success"].values():
        for cell in arm.values():
            one = next(iter(cell["per_task"].values()))
            cell["per_task"] = {t: copy.deepcopy(one) for t in tasks}
    glc_eval = report["glc"]["eval"]
    report.update(
        tasks=tasks,
        demos={
            "episodes": 248,
            "frames": 26000,
            "wanted": 25,
            "per_task": {t: 25 - (t == tasks[3]) * 2 for t in tasks},
        },
        glc={
            "steps": 150,
            "folds": [
                {"predicts": tasks[:5], "trained_on": tasks[5:], "steps": 150, "eval": glc_eval},
                {"predicts": tasks[5:], "trained_on": tasks[:5], "steps": 150, "eval": None},
            ],
        },
    )
    report["eval"]["robustness_episodes"] = 1
    md = markdown(report)
    assert "25 per task but fewer where the expert failed (libero_spatial/3 23)" in md
    assert "2 unseen setups per task clean (seeds 1000..1001) and the first 1 of them under every other" in md
    assert "| task | demos | baseline | gaze | glc | perturbed |" in md  # one row per task
    rows = [line for line in md.splitlines() if re.match(r"\| libero_spatial/\d \|", line)]
    assert len(rows) == 10 and rows[3].startswith("| libero_spatial/3 | 23 | ")
    assert "## The glc arm's estimators (cross-fitted)" in md
    assert f"| {', '.join(tasks[:5])} | 150 | 1 | {glc_eval['glc_f1']:.3f} |" in md
    assert f"| {', '.join(tasks[5:])} | 150 | 0 | - |" in md


def test_the_location_arm_trains_on_the_gaze_prior_through_a_features_head(tmp_path):
    """The location control gets the gaze arm's prior, weight and layers; only what its term supervises differs."""
    from gazereg.experiment.runner import Experiment
    from gazereg.report.ids import RunId

    cfg = replace(quick(), out=tmp_path / "x", arms=("baseline", "gaze", "location"))
    exp = Experiment(cfg)
    gaze, location, base = (
        exp.train_config(RunId(a, 0), tmp_path / a) for a in ("gaze", "location", "baseline")
    )
    assert location.gaze == replace(gaze.gaze, target="features") and gaze.gaze.target == "attention"
    assert location.gaze.prior == gaze.gaze.prior == "visuomotor" and base.gaze.prior is None
    assert replace(location, gaze=gaze.gaze, run_dir=gaze.run_dir) == gaze
