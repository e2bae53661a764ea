"""Training reports its progress on stderr (gazereg.runtime.progress), in this process and from a pool's worker
process (as the experiment's train stage runs arms), and showing it changes no number."""

import dataclasses
import multiprocessing
import re
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import torch
from safetensors.torch import load_file

from gazereg.experiment.config import smoke as experiment_smoke
from gazereg.experiment.runner import Experiment, _train_one
from gazereg.runtime.pool import exit_with_parent
from gazereg.training.config import smoke
from gazereg.training.loop import train

FINAL = re.compile(
    r"^train (\S+): 20/20 steps \(100%\), [0-9.]+ steps/s, took \d+ s, action=\d\.\d{4}$", re.M
)


def cfg(store, run_dir, **kw):
    base = smoke()
    data = dataclasses.replace(base.data, store=Path(store.root), val_fraction=0.25)
    return dataclasses.replace(base, run_dir=Path(run_dir), data=data, **kw)


def test_training_writes_its_progress_line_and_the_same_weights_as_without(tiny_store, tmp_path, capsys):
    shown = train(cfg(tiny_store, tmp_path / "shown", progress=True))
    err = capsys.readouterr().err
    assert [m.group(1) for m in FINAL.finditer(err)] == ["shown"], err
    hidden = train(cfg(tiny_store, tmp_path / "hidden", progress=False))
    assert "steps/s" not in capsys.readouterr().err
    a = load_file(str(Path(shown["checkpoint"]) / "model.safetensors"))
    b = load_file(str(Path(hidden["checkpoint"]) / "model.safetensors"))
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_a_run_trained_in_a_worker_process_reports_from_there(tiny_store, tmp_path, capfd):
    """The experiment's train stage with --parallel > 1: `_train_one` in a spawned process, whose stderr is
    the parent's."""
    run = cfg(tiny_store, tmp_path / "baseline_s0", progress=True, threads=1)
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(1, mp_context=ctx, initializer=exit_with_parent) as ex:
        result = ex.submit(_train_one, run).result(timeout=300)
    assert result["step"] == 20
    err = capfd.readouterr().err
    assert [m.group(1) for m in FINAL.finditer(err)] == ["baseline_s0"], err


def test_the_experiment_trains_every_run_with_its_progress_line(tmp_path):
    exp = Experiment(dataclasses.replace(experiment_smoke(), out=tmp_path / "exp"), "smoke")
    assert all(exp.train_config(run, d).progress for run, d in exp.run_dirs().items())
