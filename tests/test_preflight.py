"""An experiment checks what it can before its first stage (`gazereg.experiment.runner.preflight`), and
`gazereg eval` its tasks and checkpoints before its first rollout (`gazereg.evaluation.rollout.preflight`):
a mistake is one UsageError naming the option, and no stage runs, nothing is written."""

from __future__ import annotations

import importlib.util
import pickle
from dataclasses import replace

import pytest
import torch

import gazereg.experiment.preflight as preflight_module
import gazereg.experiment.runner as runner
from gazereg.evaluation.config import EvalConfig, check_tasks
from gazereg.experiment.config import smoke
from gazereg.experiment.preflight import check_glc_checkpoint, preflight
from gazereg.experiment.runner import Experiment
from gazereg.gaze.glc import GLC, GLCConfig
from gazereg.gaze.glc.checkpoint import save_glc
from gazereg.gaze.sources.glc import GLCParams
from gazereg.runtime.errors import UsageError
from gazereg.training.config import DataConfig

pytestmark = pytest.mark.skipif(importlib.util.find_spec("metaworld") is None, reason="needs Meta-World")


class _Code:
    def __reduce__(self):
        return (print, ("this must not run",))


@pytest.fixture
def no_stage_runs(monkeypatch):
    """Every stage fails the test if it starts."""
    for stage in runner.STAGES:
        monkeypatch.setattr(
            Experiment, f"stage_{stage}", lambda self, results, s=stage: pytest.fail(f"stage {s} ran")
        )


def test_a_sound_configuration_passes_the_preflight(tmp_path):
    preflight(replace(smoke(), out=tmp_path / "exp"))
    assert not (tmp_path / "exp").exists()


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (
            {"tasks": ("reach-v3", "reach-v2")},
            "--tasks: unknown Meta-World task 'reach-v2'; closest: reach-v3, ",
        ),
        (
            {"train": replace(smoke().train, data=DataConfig(tasks=("push-v3",)))},
            "--train.data.tasks: 'push-v3' is not one of the experiment's tasks (reach-v3)",
        ),
    ],
)
def test_the_experiment_refuses_before_its_first_stage(tmp_path, no_stage_runs, changes, message):
    cfg = replace(smoke(), out=tmp_path / "exp", **changes)
    with pytest.raises(UsageError) as refused:
        Experiment(cfg).run()
    assert message in str(refused.value)
    assert not (tmp_path / "exp").exists()  # not even the folder or its config.json


def test_a_gaze_source_that_cannot_be_built_is_refused_naming_its_prior(tmp_path, monkeypatch):
    def broken(params):
        raise ImportError(f"the {params.name} source needs a package that is not installed")

    monkeypatch.setattr(preflight_module, "make_gaze_source", broken)
    with pytest.raises(UsageError) as refused:
        preflight(replace(smoke(), out=tmp_path / "exp"))
    assert str(refused.value).startswith(
        "prior 'visuomotor' (gaze source visuomotor): ImportError: the visuomotor source needs"
    )


def test_a_given_glc_checkpoint_is_loaded_before_the_first_stage(tmp_path, no_stage_runs):
    code = tmp_path / "code.pt"
    with open(code, "wb") as f:
        pickle.dump({"model_state": {}, "x": _Code()}, f, protocol=2)
    cfg = replace(smoke(), out=tmp_path / "exp", glc=GLCParams(checkpoint=code))
    with pytest.raises(UsageError) as refused:
        Experiment(cfg).run()
    assert str(refused.value) == (
        f"--glc.checkpoint {code} holds pickled code, which gazereg never loads; give a safetensors or "
        "weights-only file"
    )
    assert not (tmp_path / "exp").exists()
    # a GLC folder of `gazereg glc train` passes; weights of another configuration do not
    folder = save_glc(GLC(GLCConfig.small()), None, tmp_path / "glc")
    check_glc_checkpoint(GLCParams(checkpoint=folder))
    torch.save({"model_state": {"head.weight": torch.zeros(3)}}, tmp_path / "other.pt")
    with pytest.raises(
        UsageError, match=r"^--glc\.checkpoint .*other\.pt is not a GLC checkpoint: 221 expected"
    ):
        check_glc_checkpoint(GLCParams(checkpoint=tmp_path / "other.pt", config="small"))


def test_a_glc_checkpoint_no_prior_is_made_from_is_not_required(tmp_path):
    """A run of other arms (a sitting's baseline and gaze) starts where its preset's GLC is not built yet."""
    missing = tmp_path / "glc-not-trained" / "final"
    cfg = replace(smoke(), out=tmp_path / "exp", glc=GLCParams(checkpoint=missing))
    preflight(replace(cfg, arms=("baseline", "gaze")))
    with pytest.raises(UsageError, match=r"^--glc\.checkpoint .*glc-not-trained.* does not exist"):
        preflight(cfg)


def test_evaluation_checks_its_tasks_against_the_simulator_before_anything_else(tmp_path):
    check_tasks("metaworld", ("reach-v3", "button-press-topdown-v3"))
    with pytest.raises(UsageError) as refused:
        check_tasks("metaworld", ("reach-v3", "nosuch-v3"), "--eval.tasks")
    assert str(refused.value) == (
        "--eval.tasks: unknown Meta-World task 'nosuch-v3'; closest: push-v3, reach-v3, soccer-v3 (50 v3 tasks)"
    )
    from gazereg.evaluation.rollout import evaluate

    cfg = EvalConfig(tasks=("nosuch-v3",), checkpoints=(str(tmp_path / "none"),), out=tmp_path / "eval")
    with pytest.raises(UsageError, match="unknown Meta-World task 'nosuch-v3'"):  # not the checkpoint first
        evaluate(cfg)
    assert not (tmp_path / "eval").exists()
