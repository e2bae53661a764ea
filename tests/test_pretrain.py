"""`gazereg pretrain --preset toy` end to end (stages, manifest, rerun), then fine-tuning from its policy
with `--init-from`: step 0's weights are the pretrained ones bit for bit, the pretrained tokenizer and
normalisation are kept, a paused fine-tuning run resumes to the uninterrupted run's weights, and what does not
fit (another architecture, tokenizer or policy type, a folder that is no saved policy) is refused in one line.
About a minute on 2 cores (a toy pretraining, a 2-episode collection of a held-out task, a few tiny runs)."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from gazereg import cli
from gazereg.data.store import EpisodeStore
from gazereg.envs.collect import collect
from gazereg.envs.collect_config import CollectConfig
from gazereg.experiment.config import ExperimentConfig
from gazereg.experiment.config_finetune import GENERALIST
from gazereg.experiment.pretrain import STAGES, Pretraining, store_fingerprint
from gazereg.experiment.pretrain_config import (
    PRESETS,
    finetune_flags,
    held_out_instructions,
)
from gazereg.experiment.runner import Experiment
from gazereg.policies import load_policy
from gazereg.report.ids import RunId
from gazereg.runtime.errors import UsageError
from gazereg.training.config import TrainConfig, upgrade_saved
from gazereg.training.init_from import INIT_RECORD, file_sha256
from gazereg.training.loop import train
from gazereg.training.setup import build

pytest.importorskip("metaworld")

PROGRESS_LOG = "stderr.txt"


@pytest.fixture(scope="module")
def pretrained(tmp_path_factory) -> Path:
    """A finished toy pretraining folder; what the run wrote on stderr is in the file beside it, PROGRESS_LOG."""
    out = tmp_path_factory.mktemp("pretrain") / "pt"
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert cli.main(["pretrain", "--preset", "toy", "--out", str(out)]) == 0
    (out.parent / PROGRESS_LOG).write_text(err.getvalue())
    return out


@pytest.fixture(scope="module")
def held_out_store(tmp_path_factory) -> Path:
    """Two demonstrations of a held-out ML45 task (door-unlock), at the toy preset's frame size."""
    out = tmp_path_factory.mktemp("ft") / "demos"
    cfg = CollectConfig(
        out=out, tasks=("door-unlock-v3",), episodes=2, image_size=48, max_steps=150, workers=1
    )
    collect(replace(cfg, progress=False))
    return out


def finetune_config(pretrained: Path, store: Path, run_dir: Path, **changes) -> TrainConfig:
    """`gazereg train --preset toy` with the pretrained architecture, from its policy folder."""
    base = PRESETS["toy"]().train
    return replace(
        base,
        run_dir=run_dir,
        init_from=pretrained / "policy",
        data=replace(base.data, store=store),
        **changes,
    )


def test_pretrain_runs_every_stage_and_writes_its_manifest(pretrained, capsys):
    assert all((pretrained / "stages" / f"{s}.json").exists() for s in STAGES)
    manifest = json.loads((pretrained / "manifest.json").read_text())
    policy = pretrained / "policy"
    assert manifest["policy"]["model_sha256"] == file_sha256(policy / "model.safetensors")
    assert manifest["data"]["fingerprint"] == store_fingerprint(EpisodeStore(pretrained / "demos"))
    assert manifest["command"][:2] == ["gazereg", "pretrain"] and manifest["preset"] == "toy"
    assert set(manifest["stage_seconds"]) == {"demos", "train", "eval"}
    assert manifest["policy"]["finetune_flags"] == finetune_flags(PRESETS["toy"]().train.policy)
    assert "--train.policy.max-text-len" in manifest["policy"]["finetune_flags"]
    assert manifest["evaluation"]["pooled"]["n"] == 2  # 1 episode x 2 tasks
    tokenizer = load_policy(policy).tokenizer
    assert tokenizer.kind == "words"  # its vocabulary holds every held-out instruction's words
    assert [tokenizer.unknown_words(t) for t in held_out_instructions()] == [[]] * 5
    seeds = {
        EpisodeStore(pretrained / "demos").meta(i)["seed"]
        for i in EpisodeStore(pretrained / "demos").indices()
    }
    assert min(seeds) >= 100_000
    # a rerun skips every stage and leaves the policy as it was
    before = (policy / "model.safetensors").stat().st_mtime_ns
    assert cli.main(["pretrain", "--preset", "toy", "--out", str(pretrained)]) == 0
    assert (policy / "model.safetensors").stat().st_mtime_ns == before
    assert "fine-tune with: --train.init-from" in capsys.readouterr().out


def test_a_continued_pretraining_records_the_policy_it_started_from(pretrained, tmp_path):
    """`--train.init-from` on a pretraining (the ml45_continued preset's way): the manifest names the start's
    path and SHA-256; a pretraining from scratch names none. Its demonstrations resume from a copy."""
    assert json.loads((pretrained / "manifest.json").read_text())["init_from"] is None
    out = tmp_path / "continued"
    shutil.copytree(pretrained / "demos", out / "demos")
    start = pretrained / "policy"
    args = ["pretrain", "--preset", "toy", "--out", str(out), "--train.init-from", str(start)]
    assert cli.main(args) == 0
    record = json.loads((out / "manifest.json").read_text())["init_from"]
    assert record["model_sha256"] == file_sha256(start / "model.safetensors")
    assert record["path"] == str(start)
    assert file_sha256(out / "policy" / "model.safetensors") != record["model_sha256"]  # it trained
    assert (
        json.loads((out / "stages" / "demos.json").read_text())["episodes"] == 4
    )  # resumed, not recollected
    ml45, continued = PRESETS["ml45"](), PRESETS["ml45_continued"]()
    assert continued.train.init_from == GENERALIST  # the committed generalist
    assert replace(continued, out=ml45.out, train=replace(continued.train, init_from=None)) == ml45


def test_every_stage_shows_its_progress_unless_told_not_to(pretrained):
    err = (pretrained.parent / PROGRESS_LOG).read_text()
    for label in (f"collect {pretrained / 'demos'}:", f"eval {pretrained / 'eval'}:"):
        lines = [line for line in err.splitlines() if line.startswith(label)]
        assert lines and "took" in lines[-1], label  # the stage's last line says how long it took
    assert not PRESETS["toy"]().train.progress and "train train:" not in err  # the toy's --train.no-progress
    quiet = Pretraining(replace(PRESETS["toy"](), out=pretrained, progress=False))
    assert not quiet.collect_config().progress and not quiet.train_config().progress
    toy = PRESETS["toy"]()
    loud = Pretraining(replace(toy, out=pretrained, train=replace(toy.train, progress=True)))
    assert loud.collect_config().progress and loud.train_config().progress
    assert PRESETS["ml45"]().train.progress  # the real run shows its training too


def test_pretrain_refuses_another_configuration_in_its_folder(pretrained, capsys):
    assert cli.main(["pretrain", "--preset", "toy", "--out", str(pretrained), "--demos-per-task", "3"]) == 2
    assert "demos_per_task: 2 -> 3" in capsys.readouterr().err


@pytest.mark.parametrize(
    "args, message",
    [
        (["--tasks", "reach-v3", "door-lock-v3"], "door-lock-v3 is one of ML45's held-out tasks"),
        (
            ["--train.data.extra-instructions", "Reach."],
            "the words vocabulary lacks pick, up, cube",
        ),
        (["--train.policy.max-text-len", "8"], "--train.policy.max-text-len 8 cuts"),
        (["--train.policy.tokenizer", "bytes"], "--train.policy.max-text-len 16 cuts"),
        (["--demos-per-task", "990", "--demo-max-failures", "20"], "leave the pretrain_demos range"),
        (["--tasks", "reach-v3", "nosuch-v3"], "unknown Meta-World task 'nosuch-v3'"),
    ],
)
def test_pretrain_refuses_bad_input_before_any_work(tmp_path, capsys, args, message):
    out = tmp_path / "pt"
    assert cli.main(["pretrain", "--preset", "toy", "--out", str(out), *args]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_fine_tuning_starts_from_the_pretrained_weights_tokenizer_and_normalisation(
    pretrained, held_out_store, tmp_path
):
    saved = load_policy(pretrained / "policy")
    built = build(finetune_config(pretrained, held_out_store, tmp_path / "ft"))
    mine, theirs = built.policy.state_dict(), saved.state_dict()
    assert list(mine) == list(theirs)
    assert all(torch.equal(mine[k], theirs[k]) for k in mine)  # normaliser buffers included
    assert built.policy.tokenizer.to_dict() == saved.tokenizer.to_dict()
    assert built.policy.tokenizer.unknown_words("Unlock the door by turning the lock up.") == []
    scratch = build(replace(finetune_config(pretrained, held_out_store, tmp_path / "s"), init_from=None))
    assert not torch.equal(scratch.policy.normalizer.action_mean, saved.normalizer.action_mean)
    assert built.init["model_sha256"] == file_sha256(pretrained / "policy" / "model.safetensors")


def test_a_paused_fine_tuning_run_resumes_to_the_uninterrupted_weights(pretrained, held_out_store, tmp_path):
    full = train(finetune_config(pretrained, held_out_store, tmp_path / "full", steps=4))
    paused = finetune_config(pretrained, held_out_store, tmp_path / "paused", steps=4, stop_at=2)
    assert train(paused)["step"] == 2
    resumed = train(replace(paused, stop_at=None, resume=True))
    assert resumed["step"] == 4
    a, b = load_policy(full["checkpoint"]).state_dict(), load_policy(resumed["checkpoint"]).state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    record = json.loads((tmp_path / "paused" / INIT_RECORD).read_text())
    assert record["model_sha256"] == file_sha256(pretrained / "policy" / "model.safetensors")


def test_fine_tuning_refuses_what_does_not_fit_in_one_line(pretrained, held_out_store, tmp_path):
    cfg = finetune_config(pretrained, held_out_store, tmp_path / "ft")
    narrower = replace(cfg, policy=replace(cfg.policy, dim=32))
    with pytest.raises(
        UsageError,
        match=r"parameter shapes differ: image_pos is \(1, 16, 64\) in the saved policy but \(1, 16, 32\)",
    ) as e:
        build(narrower)
    assert "\n" not in str(e.value)
    with pytest.raises(UsageError, match=r"--policy.tokenizer 'bytes' \(saved: 'words'\)"):
        build(replace(cfg, policy=replace(cfg.policy, tokenizer="bytes")))
    with pytest.raises(
        UsageError, match="train is not a saved policy: model.safetensors, tokenizer.json missing"
    ):
        build(replace(cfg, init_from=pretrained / "train"))
    other = tmp_path / "other"
    other.mkdir()
    for name in ("model.safetensors", "tokenizer.json"):
        (other / name).write_bytes((pretrained / "policy" / name).read_bytes())
    (other / "config.json").write_text(json.dumps({"type": "mlp"}))
    with pytest.raises(UsageError, match="holds a 'mlp' policy, but this run trains --policy.type vla"):
        build(replace(cfg, init_from=other))


def test_train_command_refuses_a_missing_init_folder_with_exit_2(tmp_path, capsys, held_out_store):
    args = ["train", "--data.store", str(held_out_store), "--run-dir", str(tmp_path / "r")]
    assert cli.main([*args, "--init-from", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert f"--init-from {tmp_path / 'none'}: no such folder" in err and len(err.strip().splitlines()) == 1


def test_experiment_arms_start_from_the_init_folder(tmp_path):
    base = ExperimentConfig()
    cfg = replace(base, out=tmp_path, train=replace(base.train, init_from=tmp_path / "policy"))
    run = Experiment(cfg).train_config(RunId("gaze", 0), tmp_path / "train" / "gaze_s0")
    assert run.init_from == tmp_path / "policy"


def test_a_run_saved_before_extra_instructions_compares_as_one_without_them():
    old = {"data": {"store": "x"}, "gaze": {"prior": None}}
    assert upgrade_saved(old)["data"]["extra_instructions"] == []
    assert upgrade_saved(old)["gaze"]["target"] == "attention"


@pytest.mark.parametrize("command", ["experiment", "pretrain"])
def test_experiment_and_pretrain_refuse_a_missing_init_folder_before_any_work(tmp_path, capsys, command):
    out = tmp_path / "out"
    preset = ["--preset", "toy"] if command == "pretrain" else []
    assert cli.main([command, *preset, "--out", str(out), "--train.init-from", str(tmp_path / "none")]) == 2
    assert f"--train.init-from {tmp_path / 'none'}: no such folder" in capsys.readouterr().err
    assert not out.exists()


def test_a_second_pretraining_reproduces_the_data_and_the_weights_bit_for_bit(pretrained, tmp_path):
    again = tmp_path / "pt"
    assert cli.main(["pretrain", "--preset", "toy", "--out", str(again)]) == 0
    first, second = (json.loads((d / "manifest.json").read_text()) for d in (pretrained, again))
    assert second["data"]["fingerprint"] == first["data"]["fingerprint"]
    assert second["policy"]["model_sha256"] == first["policy"]["model_sha256"]
