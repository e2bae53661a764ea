"""`gazereg experiment --preset libero`: its training demonstrations never start from an initial state the
evaluation uses, and the whole pipeline (`libero_smoke`) runs end to end in LIBERO.

Needs the LIBERO venv: `bash scripts/libero_env.sh pytest -m slow tests/envs/test_libero_experiment.py`; skipped
where hf-libero / robosuite / the assets packages are missing (the seed-level check without LIBERO:
tests/test_experiment_options.py)."""

from __future__ import annotations

import json

import pytest

from gazereg.envs.collect_config import collect_seeds
from gazereg.experiment.config_sims import libero, libero_smoke
from gazereg.experiment.demos import demo_collections
from gazereg.experiment.runner import Experiment


@pytest.mark.libero
@pytest.mark.parametrize("preset", [libero, libero_smoke])
def test_training_demos_and_evaluation_start_from_disjoint_initial_states(preset):
    """For every task, the initial states of the setups the training collection may roll out (as the demos
    stage configures it) and of every evaluation condition's setups (as the eval stage configures it), both
    mapped by LIBERO's own setup mapping (`LiberoEnv.setup_of`), do not meet."""
    from gazereg.envs.libero.setup import import_libero, resolve_task, setup_index

    import_libero(None)  # LIBERO's config, without its prompts
    cfg = preset()
    exp = Experiment(cfg)
    train = demo_collections(cfg, exp.out)["train"]
    ecfg = exp.eval_config("eval", {})
    assert len(cfg.tasks) == len(set(cfg.tasks)) and ecfg.tasks == train.tasks == cfg.tasks
    for task in cfg.tasks:
        suite, index = resolve_task(task)
        assert index is not None

        def states(seeds, suite=suite, index=index):
            return {setup_index(suite, index, s)[1] for s in seeds}

        demo_states = states(collect_seeds(train))
        assert len(demo_states) == len(collect_seeds(train))  # one initial state per demo seed
        for condition in ecfg.conditions:
            eval_states = states(ecfg.seeds(condition))
            assert len(eval_states) == len(ecfg.seeds(condition))
            assert not demo_states & eval_states, (task, condition, sorted(demo_states & eval_states))


@pytest.mark.slow
@pytest.mark.libero
def test_the_libero_smoke_experiment_runs_every_stage(tmp_path):
    from gazereg.experiment import main

    out = tmp_path / "exp"
    assert main(["--preset", "libero_smoke", "--out", str(out)]) == 0
    cfg = libero_smoke()
    report = json.loads((out / "report.json").read_text())
    arms = {"baseline", "gaze", "glc", "uniform", "perturbed"}
    assert set(report["success"]) == arms and set(report["alignment"]) == arms
    for arm in report["success"].values():
        assert arm["clean"]["n"] == 2 * 2 and arm["dim:0.7"]["n"] == arm["gaussian_noise:0.5"]["n"] == 2 * 1
    assert set(report["demos"]["per_task"]) == set(cfg.tasks) and report["demos"]["wanted"] == 2
    said = report["demos"]["instructions"]  # keyed as the evaluation names the tasks, so the table shows them
    assert set(said) == set(cfg.tasks) and all(said.values())
    folds = report["glc"]["folds"]
    assert [f["predicts"] for f in folds] == [[cfg.tasks[0]], [cfg.tasks[1]]]
    assert all(f["eval"] and f["eval"]["heldout"] for f in folds)
    prior = json.loads((out / "demos" / "priors" / "glc" / "prior.json").read_text())
    assert prior["source"]["name"] == "glc_folds" and len(prior["source"]["folds"]) == 2
    assert "gaze vs baseline | dim:0.7" in report["paired"]
    eval_info = json.loads((out / "eval" / "eval_info.json").read_text())
    assert eval_info["config"]["env"] == "libero"
    assert {e["seed"] for e in eval_info["episodes"]} == set(cfg.eval.seeds("clean"))
    md = (out / "report.md").read_text()
    assert "## The glc arm's estimators (cross-fitted)" in md and "Per task (clean)" in md
    assert (out / report["figures"]["attention"]).stat().st_size > 1000
