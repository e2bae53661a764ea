"""Policies as plugins: an installed package's entry point in the `gazereg.policies` group makes its policy
known in every process (this one, evaluation's spawned workers, a fresh `gazereg eval`), with no
`register_policy` call and no code in gazereg naming it. Nothing is installed: a dist-info folder with an
entry_points.txt on sys.path is what an installed package looks like to importlib.metadata."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest
from test_registry import _train_args
from toy_policy import ToyConfig, ToyPolicy

from gazereg.evaluation.config import EvalConfig
from gazereg.evaluation.rollout import evaluate
from gazereg.policies import available_policies, load_policy, plugins, policy_class, unregister_policy
from gazereg.runtime.config import parse
from gazereg.training.checkpoint import latest_checkpoint
from gazereg.training.config import PRESETS
from gazereg.training.loop import main

HERE = Path(__file__).resolve().parent


@pytest.fixture
def forget_toy():
    """No `toy` registered before the test, and whatever the test discovered forgotten after it."""
    unregister_policy("toy")
    yield
    unregister_policy("toy")


def installed(monkeypatch, *entries: tuple[str, str]) -> None:
    """Pretend the installed packages declare these (name, "module:Class") entry points."""
    eps = [EntryPoint(name=n, value=v, group=plugins.ENTRY_POINT_GROUP) for n, v in entries]
    monkeypatch.setattr(plugins, "policy_entry_points", lambda: eps)


def test_an_unregistered_name_is_looked_up_in_the_entry_points(monkeypatch, forget_toy):
    installed(monkeypatch)
    assert "toy" not in available_policies()
    with pytest.raises(KeyError, match="unknown policy type 'toy'"):
        policy_class("toy")
    installed(monkeypatch, ("toy", "toy_policy:ToyPolicy"))
    assert "toy" in available_policies()  # listed before it is loaded
    assert policy_class("toy") is ToyPolicy
    cfg = parse(PRESETS, ["--preset", "ci", "--policy.type", "toy", "--policy.dim", "8"], prog="t")
    assert cfg.policy == ToyConfig(dim=8)
    unregister_policy("toy")
    installed(monkeypatch, ("toy", "toy_policy:ToyConfig"))  # the config class names its policy too
    assert policy_class("toy") is ToyPolicy


@pytest.mark.parametrize(
    ("entries", "error", "match"),
    [
        ([("toy", "toy_policy:InstructionTokenizer")], TypeError, "neither a Policy nor a PolicyConfig"),
        ([("toy", "toy_policy")], TypeError, "neither a Policy nor a PolicyConfig"),
        ([("toy", "no_such_module_here:Policy")], ImportError, "failed to load: ModuleNotFoundError"),
        ([("toy", "toy_policy:ToyPolicy"), ("toy", "other:ToyPolicy")], ValueError, "several installed"),
    ],
)
def test_a_broken_plugin_is_named_in_the_error(monkeypatch, forget_toy, entries, error, match):
    installed(monkeypatch, *entries)
    with pytest.raises(error, match=match):
        policy_class("toy")


def test_an_entry_point_must_be_named_after_its_policys_type(monkeypatch, forget_toy):
    installed(monkeypatch, ("toy2", "toy_policy:ToyPolicy"))
    with pytest.raises(
        TypeError, match="names a policy of type 'toy'; the entry point's name must be its type"
    ):
        policy_class("toy2")


@pytest.fixture
def toy_plugin(tmp_path, monkeypatch, forget_toy) -> Path:
    """A 'toy-gazereg-plugin' distribution on sys.path (and PYTHONPATH, for fresh processes) declaring
    `toy = toy_policy:ToyPolicy` in the gazereg.policies group; returns the folder."""
    site = tmp_path / "site"
    info = site / "toy_gazereg_plugin-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-gazereg-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[{plugins.ENTRY_POINT_GROUP}]\ntoy = toy_policy:ToyPolicy\n")
    monkeypatch.syspath_prepend(str(site))  # spawned workers inherit sys.path
    path = [str(site), str(HERE), os.environ.get("PYTHONPATH", "")]
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(p for p in path if p))
    return site


@pytest.mark.slow
def test_an_installed_plugin_trains_and_evaluates_in_spawned_workers_and_a_fresh_process(
    toy_plugin, reach_store, tmp_path
):
    assert main(_train_args(reach_store, tmp_path / "run")) == 0  # --policy.type toy: found, not registered
    ckpt = latest_checkpoint(tmp_path / "run")
    assert isinstance(load_policy(ckpt), ToyPolicy)
    cfg = EvalConfig(
        checkpoints=(f"toy={ckpt}",),
        tasks=("reach-v3",),
        episodes=2,
        max_steps=3,
        workers=2,  # spawned processes: they only find `toy` through the entry point
        videos=0,
        out=tmp_path / "eval",
    )
    info = evaluate(cfg, progress=False)
    assert [e["seed"] for e in info["episodes"]] == [1000, 1001]
    assert all(e["arm"] == "toy" and 1 <= e["length"] <= 3 for e in info["episodes"])

    out = tmp_path / "fresh"
    args = ["eval", "--checkpoints", f"toy={ckpt}", "--tasks", "reach-v3", "--episodes", "1"]
    args += ["--max-steps", "2", "--workers", "1", "--videos", "0", "--out", str(out)]
    done = subprocess.run(
        [sys.executable, "-c", "import sys; from gazereg.cli import main; sys.exit(main())", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    episodes = json.loads((out / "eval_info.json").read_text())["episodes"]
    assert [e["arm"] for e in episodes] == ["toy"]
