"""scripts/tune_aloha.py: the Gym-Aloha recipe protocol's commands, setups, choice (successes, then the staged
reward) and table, on archives made here (no Aloha lane needed)."""

import dataclasses
import shutil
from pathlib import Path

import pytest

from gazereg.envs.aloha.setup import EPISODE_LENGTH
from gazereg.experiment import tuning
from gazereg.experiment.config import PRESETS
from gazereg.experiment.demos import demo_collections
from gazereg.experiment.tuning import built_config
from gazereg.runtime.config import config_diff, to_dict
from gazereg.runtime.errors import UsageError

ROOT = Path(__file__).resolve().parents[1]
TASKS = ("AlohaTransferCube-v0", "AlohaInsertion-v0")


@pytest.fixture
def tune(tmp_path, monkeypatch, load_script):
    module = load_script("scripts/tune_aloha.py")
    monkeypatch.setattr(module, "PROTOCOL", dataclasses.replace(module.PROTOCOL, root=tmp_path))
    return module


@pytest.fixture
def fake_archive(tune, candidate_archive):
    """`fake_archive(name, rewards, dest=None)`: an archive (at its place unless `dest`) of candidate `name` whose
    25 clean validation episodes per task reached the highest staged rewards `rewards[task]` (25 numbers; 4 is
    a success; None: no max_reward)."""

    def make(name, rewards, dest=None):
        episodes = [
            {"arm": "baseline@s0", "task": task, "condition": "clean", "seed": tune.VALIDATION_FROM + i,
             "length": EPISODE_LENGTH, "success": r == 4, **({} if r is None else {"max_reward": r})}
            for task in TASKS for i, r in enumerate(rewards[task])
        ]  # fmt: skip
        cand = tune.PROTOCOL.candidate(name)
        dest = tune.PROTOCOL.archive_path(name) if dest is None else dest
        return candidate_archive(dest, tune.PROTOCOL.command(cand), episodes)

    return make


def floor(k_touch=0, k_success=0):
    """25 rewards: `k_success` fours, then `k_touch` ones, the rest zero."""
    return [4] * k_success + [1] * k_touch + [0] * (25 - k_success - k_touch)


def test_the_candidates_differ_only_by_their_flags_and_validate_on_unused_setups(tune):
    configs = {
        c.name: to_dict(built_config(tuple(tune.PROTOCOL.command(c)))) for c in tune.PROTOCOL.candidates
    }
    preset = PRESETS["aloha"]()
    for name, cfg in configs.items():
        assert cfg["env"] == "aloha" and cfg["arms"] == ["baseline"] and cfg["train_seeds"] == [0]
        assert cfg["eval"]["seed_start"] == tune.VALIDATION_FROM and cfg["eval"]["episodes"] == 25
        assert cfg["eval"]["max_steps"] == EPISODE_LENGTH and cfg["eval"]["conditions"] == ["clean"]
        collections = demo_collections(
            built_config(tuple(tune.PROTOCOL.command(tune.PROTOCOL.candidate(name)))), Path("p")
        )
        assert collections["train"] == demo_collections(preset, Path("p"))["train"]  # the same demonstrations
    assert config_diff(configs["default"], configs["chunk50-te"], ignore=("out",)) == {
        "train.policy.chunk": [4, 50],
        "train.policy.temporal_ensemble": [None, 0.01],
    }
    assert config_diff(configs["default"], configs["chunk50-open"], ignore=("out",)) == {
        "train.policy.chunk": [4, 50],
        "train.policy.n_action_steps": [1, 25],
    }
    assert all(
        len(config_diff(configs["default"], c, ignore=("out",))) in (1, 2)
        for n, c in configs.items()
        if n != "default"
    )
    # validation setups: neither the demonstrations' (from 0, at most demos + failures) nor the evaluation's
    train = demo_collections(preset, Path("p"))["train"]
    used = set(range(train.seed_base, train.seed_base + preset.demos_per_task + preset.demo_max_failures))
    used |= set(range(preset.eval.seed_start, preset.eval.seed_start + preset.eval.episodes))
    assert not used & set(range(tune.VALIDATION_FROM, tune.VALIDATION_FROM + 25))


@pytest.mark.parametrize("lr_success", [False, True])
def test_the_choice_is_the_most_successes_then_the_higher_staged_reward(tune, fake_archive, lr_success):
    for name in [c.name for c in tune.PROTOCOL.candidates]:
        fake_archive(name, {TASKS[0]: floor(k_touch=3), TASKS[1]: floor()})
    fake_archive_path = tune.PROTOCOL.archive_path
    for name, rewards in [
        ("chunk16-te", {TASKS[0]: floor(k_touch=5), TASKS[1]: floor(k_touch=1)}),
        ("lr5e-4", {TASKS[0]: floor(k_success=1 if lr_success else 0), TASKS[1]: floor()}),
    ]:
        shutil.rmtree(fake_archive_path(name))
        fake_archive(name, rewards)
    text = tune.table()
    assert "| chunk16-te | chunks of 16, one every step, averaged | 0/50 = 0.00 |" in text
    assert "| 6 / 0 / 0 / 0 of 50 | 6 |" in text  # episodes reaching stages 1..4, summed highest reward
    if lr_success:  # one success beats any staged reward
        assert "- **lr5e-4**, learning rate 5e-4: `--train.optim.lr 5e-4` in every arm's recipe" in text
    else:  # ties on successes (0) go to the higher summed reward, not to the earlier `default`
        assert "- **chunk16-te**, chunks of 16, one every step, averaged: `--train.policy.chunk 16" in text


def test_an_episode_without_its_staged_reward_is_refused_with_one_line(tune, fake_archive, capsys):
    fake_archive("default", {TASKS[0]: [None] * 25, TASKS[1]: floor()})
    with pytest.raises(UsageError, match="has no max_reward"):
        tune.table()
    assert tune.main(["--table"]) == 2
    assert "has no max_reward" in capsys.readouterr().err


def test_a_candidate_is_run_from_the_first_ones_demonstrations_and_recorded(tune, monkeypatch, fake_archive):
    ran = []

    def fake_run(command, root):
        ran.append(command)
        out = command[command.index("--out") + 1]
        rewards = {TASKS[0]: floor(k_success=2), TASKS[1]: floor(k_touch=4)}
        (fake_archive(out.split("/")[-1], rewards, dest=root / out) / "stages" / "demos.json").write_text(
            "{}"
        )

    monkeypatch.setattr(tuning, "run_experiment", fake_run)
    assert tune.main(["--only", "default", "chunk50-te"]) == 0
    assert ran[0] == tune.PROTOCOL.command(tune.PROTOCOL.candidate("default"))
    assert ran[1][-2:] == ["--data-from", "runs/tune-aloha/default"]
    text = tune.PROTOCOL.table_path.read_text()
    assert (
        "| default | the preset" in text
        and "| 2/50 = 0.04 | AlohaTransferCube-v0 2/25, AlohaInsertion-v0 0/25 |" in text
    )
    assert "- not yet: chunk50-open, chunk16-te, steps12k, lr5e-4 to run" in text


def test_the_committed_table_is_the_archives(load_script):
    assert (
        load_script("scripts/tune_aloha.py", "tune_aloha_real").table()
        == (ROOT / "docs" / "tuning" / "aloha.md").read_text()
    )


def test_a_preset_differs_from_the_chosen_recipe_by_the_candidates_flags(tune, fake_archive):
    """`recipe_diff` names the training keys in which a preset is not the chosen candidate's run, and only
    those (evaluation setups, arms and execution keys aside)."""
    for name in [c.name for c in tune.PROTOCOL.candidates]:
        k = 5 if name == "chunk16-te" else 1
        fake_archive(name, {TASKS[0]: floor(k_touch=k), TASKS[1]: floor()})
    cand, default = tune.chosen(), tune.PROTOCOL.candidate("default")
    assert cand.name == "chunk16-te"
    before = built_config(tuple(tune.PROTOCOL.command(default)))  # the preset as it was
    assert tune.PROTOCOL.recipe_diff(cand, before) == {
        "train.policy.chunk": [16, 4],
        "train.policy.temporal_ensemble": [0.01, None],
    }
    assert tune.PROTOCOL.recipe_diff(default, before) == {}
    shutil.rmtree(tune.PROTOCOL.archive_path("lr5e-4"))
    assert tune.chosen() is None  # a candidate to run: no choice yet


def test_the_aloha_preset_trains_with_the_chosen_recipe(load_script):
    """Once every candidate has run, the `aloha` preset (every arm) is the chosen candidate's recipe."""
    tune = load_script("scripts/tune_aloha.py", "tune_aloha_chosen")
    cand = tune.chosen()
    if cand is None:
        assert "- not yet: " in (ROOT / "docs" / "tuning" / "aloha.md").read_text()
        pytest.skip("the Aloha protocol has candidates to run")
    assert tune.PROTOCOL.recipe_diff(cand, PRESETS["aloha"]()) == {}


def test_the_candidates_build_the_configurations_they_ran_whatever_recipe_the_preset_takes(tune, monkeypatch):
    """The pinned flags hold every key a candidate changes: with the preset's recipe (and evaluation) changed
    to any candidate's, every candidate's command still builds the configuration it built before."""
    from gazereg.experiment import config

    def built(cand):
        return to_dict(tuning.parse(config.PRESETS, tune.PROTOCOL.command(cand)[2:], prog="t"))

    before = {c.name: built(c) for c in tune.PROTOCOL.candidates}
    presets = {
        c.name: built_config(tuple(tune.PROTOCOL.command(c))) for c in tune.PROTOCOL.candidates
    }  # the preset as it would be after choosing each candidate (its evaluation changed below)
    for name, cfg in presets.items():
        ev = dataclasses.replace(cfg.eval, conditions=("clean", "dim:0.7"), robustness_episodes=5)
        cfg = dataclasses.replace(cfg, eval=ev)
        monkeypatch.setitem(config.PRESETS, "aloha", lambda cfg=cfg: cfg)
        assert {c.name: built(c) for c in tune.PROTOCOL.candidates} == before, name
