"""Registries that register (issue 34 item 3): a simulator, a gaze source and an arm that nothing in gazereg
names (tests/plugins/toy_plugins.py) are found through the entry-point groups `gazereg.simulators`,
`gazereg.gaze_sources` and `gazereg.arms` and run from the command line (`gazereg.cli.main`, in process).
Nothing is installed: a dist-info folder with an entry_points.txt on sys.path is what an installed package
looks like to importlib.metadata."""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest

from gazereg import cli
from gazereg.data.store import EpisodeStore
from gazereg.envs.base import simulator_names, unregister_simulator
from gazereg.evaluation.config import EvalConfig, check_tasks
from gazereg.experiment.arms import arm_prior, gaze_target
from gazereg.experiment.config import PRESETS
from gazereg.gaze.sources import available_gaze_sources, unregister_gaze_source
from gazereg.report.build import ReportSpec, StageOutputs, build_report
from gazereg.report.ids import RunId
from gazereg.runtime.config import parse
from gazereg.runtime.errors import UsageError
from gazereg.training.arms import Arm, arm_names, gaze_controls, register_arm, unregister_arm

ENTRY_POINTS = """\
[gazereg.simulators]
toy = toy_plugins:SIMULATOR

[gazereg.gaze_sources]
toy = toy_plugins:ToyGazeParams

[gazereg.arms]
toy = toy_plugins:ARM
"""


def _forget_toy() -> None:
    unregister_simulator("toy")
    unregister_gaze_source("toy")
    unregister_arm("toy")
    sys.modules.pop("toy_plugins", None)  # importing it again registers its gaze source again


@pytest.fixture
def no_toy():
    """Nothing named `toy` registered before the test, and whatever the test registered forgotten after."""
    _forget_toy()
    yield
    _forget_toy()


@pytest.fixture
def installed(tmp_path, monkeypatch, no_toy):
    """A package providing the toy simulator, gaze source and arm, as importlib.metadata sees one."""
    site = tmp_path / "site"
    dist = site / "toy_gazereg_plugins-0.1.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-gazereg-plugins\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(ENTRY_POINTS)
    monkeypatch.syspath_prepend(str(site))


def _collect(store, capsys) -> int:
    args = ["--env", "toy", "--tasks", "dot-left", "dot-right", "--episodes", "2", "--max-failures", "0"]
    return cli.main(
        ["collect", *args, "--image-size", "16", "--workers", "1", "--no-progress", "--out", str(store)]
    )


def test_without_the_plugin_the_toy_names_are_refused_in_one_line(tmp_path, capsys, no_toy):
    assert (
        "toy" not in simulator_names() and "toy" not in available_gaze_sources() and "toy" not in arm_names()
    )
    assert _collect(tmp_path / "demos", capsys) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "gazereg collect: error: --env: unknown simulator 'toy'; choose one of ['aloha', 'libero', 'metaworld']"
    ]
    assert not (tmp_path / "demos").exists()
    with pytest.raises(
        UsageError,
        match=r"^--env: unknown simulator 'toy'; choose one of \['aloha', 'libero', 'metaworld'\]$",
    ):
        EvalConfig(env="toy")
    with pytest.raises(
        UsageError, match=r"^--arms: unknown arm 'toy'; choose from baseline, gaze, perturbed"
    ):
        parse(PRESETS, ["--preset", "smoke", "--arms", "baseline", "toy"], prog="gazereg experiment")


def test_a_plugin_simulator_collects_from_the_command_line(tmp_path, capsys, installed):
    assert "toy" in simulator_names()  # listed before it is loaded
    store = tmp_path / "demos"
    assert _collect(store, capsys) == 0
    episodes = EpisodeStore(store)
    assert len(episodes.indices()) == 4
    ep = episodes.read(episodes.indices()[0])
    assert ep.task == "dot-left" and ep.frames["cam"].shape == (4, 16, 16, 3)  # the toy's defaults filled in
    # The evaluation and the experiment take it by name as well; its collector checks the tasks.
    assert EvalConfig(env="toy", tasks=("dot-right",)).env == "toy"
    with pytest.raises(UsageError, match="--tasks: unknown toy tasks"):
        check_tasks("toy", ["dot-up"])
    cfg = parse(
        PRESETS, ["--preset", "smoke", "--env", "toy", "--eval.env", "toy", "--tasks", "dot-left"], prog="x"
    )
    assert cfg.env == "toy"


def test_a_plugin_gaze_source_makes_priors_from_the_command_line(tmp_path, capsys, installed):
    assert "toy" in available_gaze_sources()
    store = tmp_path / "demos"
    assert _collect(store, capsys) == 0
    args = ["--store", str(store), "--source", "toy", "--source-params", "column=0.75", "--camera", "cam"]
    assert (
        cli.main(
            ["priors", *args, "--size", "4", "4", "--aggregation.past", "0", "--aggregation.future", "0"]
        )
        == 0
    )
    episodes = EpisodeStore(store)
    heat, valid = episodes.read_prior("toy", episodes.indices()[0])
    assert heat.shape == (4, 4, 4) and valid.all()
    assert np.unravel_index(int(np.argmax(heat[0])), (4, 4)) == (2, 3)  # the middle row, column 0.75
    assert cli.main(["priors", *args[:4], "--source-params", "row=1"]) == 2  # its own parameters, checked
    assert "gaze source 'toy' has no parameter 'row'; its parameters: column" in capsys.readouterr().err


def _report_with(arms: tuple[str, ...], tmp_path) -> dict:
    def episodes(arm: str, successes: list[int]) -> list[dict]:
        run = RunId(arm, 0)
        return [
            {"arm": str(run), "task": "dot-left", "condition": "clean", "seed": 1000 + i, "success": bool(s)}
            for i, s in enumerate(successes)
        ]

    outcomes = {"baseline": [0, 0, 1, 0], "gaze": [1, 1, 0, 1], "toy": [1, 0, 0, 0]}
    runs = [RunId(a, 0) for a in arms]
    outputs = StageOutputs(
        episodes=[e for a in arms for e in episodes(a, outcomes[a])],
        checkpoint_episodes=[],
        demos={"episodes": 4, "frames": 16},
        glc=None,
        final_metrics={run: {} for run in runs},
        metrics_files={run: tmp_path / "none.jsonl" for run in runs},
        alignment={run: {"gaze_kl": 1.0} for run in runs},
        attention_figure="figures/attention.png",
        date="today",
        stage_times={},
    )
    spec = ReportSpec(
        preset="unit",
        tasks=("dot-left",),
        arms=arms,
        train_seeds=(0,),
        train_steps=10,
        batch_size=4,
        gaze_weight=0.1,
        gaze_layers=(-1,),
        eval_episodes=4,
        eval_conditions=("clean",),
        eval_seed_start=1000,
        convergence_episodes=2,
        threshold=0.5,
        config={},
    )
    return build_report(spec, outputs, tmp_path)


def test_a_plugin_arm_is_an_experiment_arm_and_a_control_of_the_report(tmp_path, installed):
    assert "toy" in arm_names()
    # `gazereg experiment --arms baseline gaze toy`, up to its plan: the configuration the command builds, the
    # prior the priors stage makes for the toy arm and the target its training run gets.
    cfg = parse(
        PRESETS, ["--preset", "smoke", "--arms", "baseline", "gaze", "toy"], prog="gazereg experiment"
    )
    assert cfg.arms == ("baseline", "gaze", "toy")
    prior = arm_prior("toy", cfg)
    assert prior.name == "toy" and prior.source.name == "toy" and prior.source.column == 0.25
    assert gaze_target("toy") == "attention"
    assert gaze_controls(cfg.arms) == ("toy",)
    # The report reads the control role from the registry: the gaze arm is tested against the toy arm.
    report = _report_with(("baseline", "gaze", "toy"), tmp_path)
    test = report["paired"]["gaze vs toy | clean"]
    assert test["pairs"] == 4 and test["gaze_only"] == 2 and test["toy_only"] == 0
    assert "toy vs baseline | clean" in report["paired"]


def test_an_arm_registered_in_code_is_one_registration(tmp_path, no_toy):
    from gazereg.gaze.sources.simple import UniformParams
    from gazereg.training.arms import PriorSpec

    register_arm(
        Arm("toy", prior=lambda cfg, names: PriorSpec("uniform", UniformParams()), target="features")
    )
    cfg = parse(
        PRESETS, ["--preset", "smoke", "--arms", "baseline", "gaze", "toy"], prog="gazereg experiment"
    )
    assert arm_prior("toy", cfg).source == UniformParams() and gaze_target("toy") == "features"
    assert (
        "gaze vs toy | clean" not in _report_with(("baseline", "gaze", "toy"), tmp_path)["paired"]
    )  # no control
    with pytest.raises(ValueError, match="arm 'toy' is already registered"):
        register_arm(dataclasses.replace(Arm("toy", prior=lambda cfg, names: None), control=True))


@pytest.mark.sim
def test_a_plugin_arm_runs_a_smoke_experiment_from_the_command_line(tmp_path, capsys, installed):
    """`gazereg experiment --arms baseline gaze toy` end to end at smoke size (Meta-World; about 40 s on 2
    cores): the priors stage makes the toy source's prior, the toy arm trains and is evaluated, and the report
    tests the gaze arm against it."""
    import json

    out = tmp_path / "exp"
    args = ["--preset", "smoke", "--arms", "baseline", "gaze", "toy", "--eval.conditions", "clean"]
    assert (
        cli.main(["experiment", *args, "--parallel", "1", "--convergence-points", "1", "--out", str(out)])
        == 0
    )
    report = json.loads((out / "report.json").read_text())
    assert set(report["success"]) == {"baseline", "gaze", "toy"}
    assert {"gaze vs toy | clean", "toy vs baseline | clean"} <= set(report["paired"])
    assert "toy" in EpisodeStore(out / "demos").prior_names()
