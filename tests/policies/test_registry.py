"""The policy registry and the Policy interface: a policy defined outside the library (tests/policies/
toy_policy.py) is chosen with `--policy.type`, trains with and without the gaze term, resumes, loads and is
rolled out in Meta-World, with no change to training or evaluation code."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
import torch
from toy_policy import ToyConfig, ToyPolicy

from gazereg.data.dataset import describe_store
from gazereg.evaluation.config import EvalConfig
from gazereg.evaluation.rollout import evaluate
from gazereg.policies import (
    Policy,
    available_policies,
    load_policy,
    make_policy,
    policy_class,
    policy_config_class,
    register_policy,
)
from gazereg.policies.vla import VLAConfig, VLAPolicy
from gazereg.runtime.config import parse, to_dict
from gazereg.runtime.errors import UsageError
from gazereg.training.checkpoint import latest_checkpoint
from gazereg.training.config import PRESETS, TrainConfig, smoke
from gazereg.training.logger import read_metrics
from gazereg.training.loop import main, train


def test_the_registry_knows_the_builtins_and_checks_what_it_registers(toy_policy):
    assert "vla" in available_policies() and "toy" in available_policies()
    assert policy_class("vla") is VLAPolicy and policy_config_class("toy") is ToyConfig
    register_policy(ToyPolicy)  # again: a no-op
    with pytest.raises(KeyError, match="unknown policy type 'nope'.*registered"):
        policy_class("nope")
    with pytest.raises(TypeError, match="not a gazereg.policies.base.Policy"):
        register_policy(torch.nn.Linear)

    class Impostor(ToyPolicy):
        pass

    with pytest.raises(ValueError, match="'toy' is already registered"):
        register_policy(Impostor)


def test_policy_type_on_the_command_line_picks_the_registered_config(toy_policy):
    cfg = parse(PRESETS, ["--preset", "ci", "--policy.type", "toy", "--policy.dim", "8"], prog="t")
    assert isinstance(cfg, TrainConfig) and cfg.policy == ToyConfig(dim=8) and cfg.steps == smoke().steps
    assert to_dict(cfg)["policy"] == {"type": "toy", **ToyConfig(dim=8).to_dict()}
    same = parse(PRESETS, ["--preset", "ci", "--policy.type=vla", "--policy.depth", "3"], prog="t")
    assert same.policy == dataclasses.replace(smoke().policy, depth=3)  # the preset's VLA config is kept
    assert to_dict(same)["policy"]["type"] == "vla" and "policy_type" not in to_dict(same)
    with pytest.raises(UsageError, match="unknown policy type 'nope'"):
        parse(PRESETS, ["--policy.type", "nope"], prog="t", default="ci")


def test_make_policy_builds_the_configs_registered_type(toy_policy, reach_store):
    data = describe_store(reach_store, reach_store.indices())
    p = make_policy(ToyConfig(), data)
    assert isinstance(p, ToyPolicy) and isinstance(p, Policy) and p.name == "toy"
    assert p.config.cameras == ("corner2",) and p.config.n_instructions == 1
    assert isinstance(make_policy(VLAConfig(image_hw=(48, 48)), data), VLAPolicy)


def _train_args(store, run, *extra):
    return [
        "--preset", "ci", "--policy.type", "toy", "--data.store", str(store.root), "--run-dir", str(run),
        "--steps", "6", "--save-every", "6", "--eval-every", "3", "--log-every", "3", *extra,
    ]  # fmt: skip


def test_a_registered_policy_trains_with_and_without_gaze_and_is_evaluated(toy_policy, reach_store, tmp_path):
    gaze = ("--gaze.prior", "square", "--gaze.layers", "0", "--gaze.weight", "1.0")
    assert main(_train_args(reach_store, tmp_path / "base")) == 0
    assert main(_train_args(reach_store, tmp_path / "gaze", *gaze)) == 0
    base, with_gaze = (read_metrics(tmp_path / r / "metrics.jsonl") for r in ("base", "gaze"))
    assert [r["step"] for r in base] == [3, 6] and "loss/gaze_kl" not in base[-1]
    assert {"loss/gaze_kl", "align_val/kl", "gaze/weight"} <= set(with_gaze[-1])
    saved = json.loads((tmp_path / "gaze" / "config.json").read_text())
    assert saved["policy"]["type"] == "toy" and saved["policy"]["cameras"] == ["corner2"]
    ckpt = latest_checkpoint(tmp_path / "gaze")
    policy = load_policy(ckpt)
    assert isinstance(policy, ToyPolicy) and policy.config == ToyConfig.from_dict(saved["policy"])
    base_policy = load_policy(latest_checkpoint(tmp_path / "base"))
    pairs = zip(base_policy.state_dict().values(), policy.state_dict().values())
    assert not all(torch.equal(x, y) for x, y in pairs)  # the gaze term changed the update

    cfg = EvalConfig(
        checkpoints=(f"toy={ckpt}",),
        tasks=("reach-v3",),
        episodes=2,
        max_steps=5,
        workers=1,  # a policy registered in this process only: evaluate in this process
        videos=1,
        out=tmp_path / "eval",
    )
    info = evaluate(cfg, progress=False)
    assert [e["seed"] for e in info["episodes"]] == [1000, 1001]
    assert all(e["arm"] == "toy" and 1 <= e["length"] <= 5 for e in info["episodes"])
    assert Path(info["episodes"][0]["video"]).exists()  # filmed with the attention overlay (probe + geometry)


def test_bad_layers_and_a_resume_with_another_type_fail_early(toy_policy, reach_store, tmp_path):
    with pytest.raises(ValueError, match="out of range for a 1-layer policy"):
        main(_train_args(reach_store, tmp_path / "bad", "--gaze.prior", "square"))  # default layers (-2, -1)
    cfg = parse(PRESETS, _train_args(reach_store, tmp_path / "run", "--stop-at", "3"), prog="t")
    train(cfg)
    vla = dataclasses.replace(cfg, policy=smoke().policy, resume=True)
    with pytest.raises(ValueError, match="holds a 'toy' policy; resume it with --policy.type toy"):
        train(vla)
    out = train(dataclasses.replace(cfg, resume=True, stop_at=None))
    assert out["step"] == 6 and isinstance(load_policy(out["checkpoint"]), ToyPolicy)
