"""`gazereg train` under bad options, changed configs, kills and damaged files (the reliability issue)."""

import dataclasses
import json
import logging
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from gazereg.cli import main as cli_main
from gazereg.experiment.config import PRESETS as EXPERIMENT_PRESETS
from gazereg.experiment.runner import Experiment
from gazereg.runtime.config import ConfigMismatch, save_config
from gazereg.runtime.errors import UsageError
from gazereg.training import setup as training_setup
from gazereg.training.checkpoint import DamagedCheckpoint, list_checkpoints, read_checkpoint
from gazereg.training.config import DataConfig, GazeConfig, OptimConfig, TrainConfig, smoke
from gazereg.training.logger import read_metrics
from gazereg.training.loop import train

ROOT = Path(__file__).resolve().parents[2]


def cfg(store, run_dir, **kw):
    base = smoke()
    data = dataclasses.replace(base.data, store=Path(store.root), val_fraction=0.25)
    return dataclasses.replace(base, run_dir=Path(run_dir), data=data, **kw)


def steps_of(run_dir):
    return [r["step"] for r in read_metrics(Path(run_dir) / "metrics.jsonl")]


def weights(run_dir, step):
    return load_file(str(Path(run_dir) / "checkpoints" / f"step_{step:06d}" / "model.safetensors"))


# ----- options are validated when a config is built ---------------------------------------------------------
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--gaze.weight", "nan"], "--gaze.weight must be a finite number >= 0, got nan"),
        (["--gaze.weight", "inf"], "--gaze.weight must be a finite number >= 0, got inf"),
        (["--gaze.weight", "-1"], "--gaze.weight must be a finite number >= 0, got -1.0"),
        (["--steps", "0"], "--steps must be an integer >= 1, got 0"),
        (["--steps", "-5"], "--steps must be an integer >= 1, got -5"),
        (["--save-every", "0"], "--save-every must be an integer >= 1, got 0"),
        (["--eval-every", "0"], "--eval-every must be an integer >= 1, got 0"),
        (["--log-every", "0"], "--log-every must be an integer >= 1, got 0"),
        (["--batch-size", "0"], "--batch-size must be an integer >= 1, got 0"),
        (["--optim.lr", "nan"], "--optim.lr must be a finite number > 0, got nan"),
        (["--optim.betas", "0.9", "1.0"], "--optim.betas must be a finite number in [0, 1), got 1.0"),
        (["--optim.min-lr-frac", "2"], "--optim.min-lr-frac must be a finite number in [0, 1], got 2.0"),
        (["--optim.ema-decay", "1"], "--optim.ema-decay must be a finite number in [0, 1), got 1.0"),
        (["--data.val-fraction", "1"], "--data.val-fraction must be a finite number in [0, 1), got 1.0"),
        (["--gaze.patch-eps", "0"], "--gaze.patch-eps must be a finite number > 0, got 0.0"),
        (["--threads", "0"], "--threads must be an integer >= 1, got 0"),
        (["--stop-at", "0"], "--stop-at must be an integer >= 1, got 0"),
        (["--keep-checkpoints", "-1"], "--keep-checkpoints must be an integer >= 0, got -1"),
    ],
)
def test_bad_options_exit_2_with_one_line_naming_the_option(tiny_store, tmp_path, capsys, args, message):
    run = tmp_path / "run"
    argv = ["train", "--preset", "ci", "--data.store", str(tiny_store.root), "--run-dir", str(run), *args]
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"gazereg train: error: {message}"]
    assert not run.exists()


def test_configs_are_validated_when_built_from_python():
    with pytest.raises(UsageError, match="--save-every must be an integer >= 1, got 0"):
        dataclasses.replace(smoke(), save_every=0)
    with pytest.raises(UsageError, match="--gaze.weight must be a finite number >= 0, got nan"):
        GazeConfig(weight=float("nan"))
    with pytest.raises(UsageError, match="--optim.warmup-steps must be an integer >= 0, got -1"):
        OptimConfig(warmup_steps=-1)
    with pytest.raises(UsageError, match="--data.num-workers must be an integer >= 0, got -1"):
        DataConfig(num_workers=-1)
    with pytest.raises(UsageError, match="--device must be one of auto, cpu, cuda, got 'gpu'"):
        TrainConfig(device="gpu")  # type: ignore[arg-type]
    with pytest.raises(UsageError, match="--steps must be an integer >= 1, got 2.5"):
        TrainConfig(steps=2.5)  # type: ignore[arg-type]


def test_an_experiment_names_the_nested_option():
    from gazereg.runtime.config import parse

    with pytest.raises(UsageError, match="--train.gaze.weight must be a finite number >= 0, got nan"):
        parse(EXPERIMENT_PRESETS, ["--preset", "smoke", "--train.gaze.weight", "nan"], prog="x")


# ----- a resumed run is the same run ------------------------------------------------------------------------
def test_resume_with_another_config_is_refused_naming_every_changed_key(tiny_store, tmp_path):
    run = tmp_path / "run"
    first = cfg(tiny_store, run, steps=8, save_every=4, eval_every=4, stop_at=4)
    train(first)
    saved_config = (run / "config.json").read_text()
    changed = dataclasses.replace(
        first,
        resume=True,
        stop_at=None,
        seed=1,
        optim=dataclasses.replace(first.optim, lr=2e-3),
        gaze=GazeConfig(prior="square", weight=0.5),
    )
    with pytest.raises(ConfigMismatch) as info:
        train(changed)
    text = str(info.value)
    assert str(run / "checkpoints" / "step_000004") in text
    for change in ("seed: 0 -> 1", "optim.lr: 0.001 -> 0.002", "gaze.prior: None -> 'square'"):
        assert change in text
    assert "gaze.weight: 0.1 -> 0.5" in text and "--run-dir" in text
    assert "stop_at" not in text.split(";")[0]  # execution keys may change
    with pytest.raises(ConfigMismatch, match=r"steps: 8 -> 12"):  # the LR schedule spans `steps`
        train(dataclasses.replace(first, resume=True, steps=12))
    assert (run / "config.json").read_text() == saved_config  # a refused resume rewrites nothing
    assert [s for s, _ in list_checkpoints(run)] == [4] and steps_of(run) == [4]


def test_resume_may_change_execution_keys_and_continues_the_same_trajectory(tiny_store, tmp_path):
    kw = dict(steps=8, eval_every=4, log_every=2, optim=OptimConfig(lr=1e-3, warmup_steps=2))
    train(cfg(tiny_store, tmp_path / "straight", save_every=4, **kw))
    train(cfg(tiny_store, tmp_path / "split", save_every=4, stop_at=4, **kw))
    split = cfg(
        tiny_store, tmp_path / "split", resume=True, save_every=2, keep_checkpoints=1, progress=True, **kw
    )
    out = train(dataclasses.replace(split, data=dataclasses.replace(split.data, in_memory=False)))
    assert out["step"] == 8 and [s for s, _ in list_checkpoints(tmp_path / "split")] == [8]
    a, b = weights(tmp_path / "straight", 8), weights(tmp_path / "split", 8)
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_experiment_refuses_another_config_through_the_shared_check(tmp_path):
    cfg_a = dataclasses.replace(EXPERIMENT_PRESETS["smoke"](), out=tmp_path / "exp")
    (tmp_path / "exp").mkdir()
    save_config(cfg_a, tmp_path / "exp" / "config.json")
    Experiment(dataclasses.replace(cfg_a, parallel=cfg_a.parallel + 1)).check_resumable()  # execution key
    cfg_b = dataclasses.replace(cfg_a, train=dataclasses.replace(cfg_a.train, steps=cfg_a.train.steps + 1))
    with pytest.raises(ConfigMismatch, match=rf"train.steps: {cfg_a.train.steps} -> {cfg_a.train.steps + 1}"):
        Experiment(cfg_b).check_resumable()
    assert issubclass(ConfigMismatch, UsageError)


# ----- restarts, partial lines and damaged checkpoints ------------------------------------------------------
class Killed(Exception):
    pass


@pytest.mark.parametrize("resume", [False, True])
def test_a_restart_before_the_first_checkpoint_starts_a_clean_metrics_file(tiny_store, tmp_path, resume):
    run = tmp_path / "run"
    c = cfg(tiny_store, run, steps=8, save_every=8, eval_every=4, log_every=1)

    def kill_at_first_eval(step, policy):
        raise Killed

    with pytest.raises(Killed):
        train(c, callbacks=[kill_at_first_eval])
    assert steps_of(run) == [1, 2, 3] and not list_checkpoints(run)
    train(dataclasses.replace(c, resume=resume))  # --resume with no checkpoint: a warning, then from scratch
    assert steps_of(run) == list(range(1, 9))


def test_a_partial_last_metrics_line_is_skipped_and_dropped_on_resume(tiny_store, tmp_path, caplog):
    run = tmp_path / "run"
    c = cfg(tiny_store, run, steps=8, save_every=4, eval_every=4, log_every=1)
    train(dataclasses.replace(c, stop_at=4))
    with open(run / "metrics.jsonl", "a") as f:
        f.write('{"epoch": 1.2, "loss": 0.5')  # a write cut short by a kill
    with caplog.at_level(logging.WARNING):
        assert steps_of(run) == [1, 2, 3, 4]
    assert "metrics.jsonl:5: skipping a partial last line" in caplog.text
    train(dataclasses.replace(c, resume=True))
    assert steps_of(run) == list(range(1, 9))
    lines = (run / "metrics.jsonl").read_text().splitlines()
    assert len(lines) == 8 and all(json.loads(line) for line in lines)


def test_a_bad_metrics_line_before_the_last_names_the_file_and_line(tmp_path):
    path = tmp_path / "metrics.jsonl"
    path.write_text('{"step": 1}\nnot json\n{"step": 3}\n')
    with pytest.raises(ValueError, match=rf"{path}:2 is not a metrics record"):
        read_metrics(path)


def test_a_damaged_checkpoint_is_named_and_resume_falls_back_to_the_previous_one(
    tiny_store, tmp_path, caplog
):
    kw = dict(steps=8, save_every=2, eval_every=4, log_every=1, optim=OptimConfig(lr=1e-3, ema_decay=0.9))
    train(cfg(tiny_store, tmp_path / "straight", **kw))
    run = tmp_path / "run"
    train(cfg(tiny_store, run, stop_at=6, **kw))
    damaged = run / "checkpoints" / "step_000006" / "training_state" / "optimizer.safetensors"
    damaged.write_bytes(damaged.read_bytes()[:100])  # truncated
    with pytest.raises(DamagedCheckpoint, match=str(damaged)):
        read_checkpoint(damaged.parents[1])
    with caplog.at_level(logging.WARNING):
        out = train(cfg(tiny_store, run, resume=True, **kw))
    assert f"checkpoint file {damaged} cannot be read" in caplog.text and "falling back" in caplog.text
    assert out["step"] == 8 and steps_of(run) == list(range(1, 9))
    keys = ("step", "loss", "loss/action", "lr", "grad_norm")
    straight = read_metrics(tmp_path / "straight" / "metrics.jsonl")
    assert [[r[k] for k in keys] for r in read_metrics(run / "metrics.jsonl")] == [
        [r[k] for k in keys] for r in straight
    ]
    a, b = weights(tmp_path / "straight", 8), weights(run, 8)
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_resume_with_every_checkpoint_damaged_names_the_newest(tiny_store, tmp_path):
    run = tmp_path / "run"
    c = cfg(tiny_store, run, steps=8, save_every=4, eval_every=4, stop_at=4)
    train(c)
    state = run / "checkpoints" / "step_000004" / "training_state" / "state.json"
    state.write_text(state.read_text()[:20])
    with pytest.raises(DamagedCheckpoint, match=rf"checkpoint file {state} cannot be read"):
        train(dataclasses.replace(c, resume=True, stop_at=None))


# ----- the gaze and attention grids are checked against each other -------------------------------------------
def test_the_trainer_refuses_gaze_targets_made_for_another_patch_grid(tiny_store, tmp_path, monkeypatch):
    build = training_setup.build

    def build_with_another_grid(c):
        built = build(c)
        rows, cols = built.attention_grid
        assert built.gaze_grid == (rows, cols) == (4, 4)
        built.gaze_grid = (rows // 2, cols * 2)  # the same patch count on another grid
        return built

    monkeypatch.setattr(training_setup, "build", build_with_another_grid)
    c = cfg(
        tiny_store, tmp_path / "run", steps=2, save_every=2, eval_every=2, gaze=GazeConfig(prior="square")
    )
    with pytest.raises(ValueError, match=r"gaze grid \(2, 8\) and attention grid \(4, 4\) differ"):
        train(c)


# ----- temporaries of a killed run are swept ----------------------------------------------------------------
KILL_WHILE_SAVING = """
import os, signal, sys
import gazereg.training.checkpoint as checkpoint
from gazereg.training.loop import main

def killed(*args, **kwargs):
    os.kill(os.getpid(), signal.SIGKILL)

checkpoint.save_tensors_json = killed  # the process dies inside the checkpoint's atomic folder
main(sys.argv[1:])
"""


@pytest.mark.slow
def test_a_killed_train_leaves_a_temporary_that_the_next_start_removes(tiny_store, tmp_path):
    run = tmp_path / "run"
    args = ["--preset", "ci", "--data.store", str(tiny_store.root), "--run-dir", str(run), "--steps", "4"]
    args += ["--save-every", "2", "--eval-every", "2", "--data.val-fraction", "0.25"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    r = subprocess.run(
        [sys.executable, "-c", KILL_WHILE_SAVING, *args], capture_output=True, text=True, env=env, timeout=240
    )
    assert r.returncode == -signal.SIGKILL, r.stderr[-3000:]
    temps = list((run / "checkpoints").glob(".step_000002.*.tmp"))
    assert len(temps) == 1 and temps[0].is_dir() and not list_checkpoints(run)
    c = cfg(tiny_store, run, steps=4, save_every=2, eval_every=2)
    train(c)
    assert not list(run.rglob("*.tmp")) and [s for s, _ in list_checkpoints(run)] == [2, 4]
