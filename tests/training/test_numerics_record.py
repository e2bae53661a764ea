"""A training run records the numerics key of the machine that trains it (numerics.json, one entry per attempt),
so that a report built later, elsewhere, or pooled names the machines that trained, not its own."""

import dataclasses
import json
import logging
from pathlib import Path

import pytest
import torch

from gazereg.runtime import hardware
from gazereg.runtime.errors import UsageError
from gazereg.runtime.hardware import NumericsKey
from gazereg.training.config import ci
from gazereg.training.loop import train
from gazereg.training.numerics import NUMERICS_FILE, TrainingAttempt, read_numerics, record_numerics


def cfg(store, run_dir, **kw):
    """The `ci` recipe for 3 steps in float32 (a checkpoint at each step)."""
    base = ci()
    data = dataclasses.replace(base.data, store=Path(store.root), val_fraction=0.25)
    common = dict(steps=3, save_every=1, eval_every=3, log_every=1, eval_batch_size=4, mixed_precision="no")
    return dataclasses.replace(base, run_dir=Path(run_dir), data=data, **{**common, **kw})


def as_another_machine(monkeypatch):
    """This machine seen as one no machine of this kind is (a vendor of its own, torch's scalar DEFAULT
    capability): another key, same precision, whichever CPU the test runs on (an AMD EPYC with AVX2 among them)."""
    monkeypatch.setattr(hardware, "cpu_flags", lambda: frozenset({"sse2"}))
    monkeypatch.setattr(hardware, "cpu_identity", lambda: ("OtherVendor", "Other CPU 1"))
    monkeypatch.setattr(torch.backends.cpu, "get_cpu_capability", lambda: "DEFAULT")


def test_a_short_training_records_the_key_of_this_machine(tiny_store, tmp_path):
    run = tmp_path / "run"
    train(cfg(tiny_store, run))
    saved = json.loads((run / NUMERICS_FILE).read_text())
    here = NumericsKey.here("no")
    assert saved == {
        "attempts": [
            {"attempt": 1, "start_step": 0, "key": here.to_dict(), "cpu_model": hardware.cpu_identity()[1]}
        ]
    }
    assert read_numerics(run) == (TrainingAttempt(1, 0, here, hardware.cpu_identity()[1]),)


def test_a_resume_on_another_machine_records_both_attempts(tiny_store, tmp_path, monkeypatch, caplog):
    run = tmp_path / "run"
    train(cfg(tiny_store, run, stop_at=2))
    here = NumericsKey.here("no")
    as_another_machine(monkeypatch)
    with caplog.at_level(logging.WARNING, logger="gazereg.training.numerics"):
        train(cfg(tiny_store, run, resume=True))
    assert "resumed on a machine whose numerics differ" in caplog.text and "cpu_capability: " in caplog.text
    other = NumericsKey("no", "DEFAULT", (), "OtherVendor", torch.__version__, here.gpu)
    attempts = read_numerics(run)
    assert [(a.attempt, a.start_step, a.key) for a in attempts] == [(1, 0, here), (2, 2, other)]
    assert attempts[1].cpu_model == "Other CPU 1"
    train(cfg(tiny_store, run, resume=True))  # nothing left to train: no attempt recorded
    assert read_numerics(run) == attempts


def test_a_run_resumed_from_before_the_record_starts_with_an_unknown_attempt(tiny_store, tmp_path):
    run = tmp_path / "run"
    train(cfg(tiny_store, run, stop_at=2))
    (run / NUMERICS_FILE).unlink()  # as a run trained before runs recorded their key
    train(cfg(tiny_store, run, resume=True))
    assert [(a.attempt, a.start_step, a.key) for a in read_numerics(run)] == [
        (1, 0, None),
        (2, 2, NumericsKey.here("no")),
    ]


def test_a_start_from_scratch_replaces_the_record_and_a_damaged_one_is_refused(tmp_path):
    record_numerics(tmp_path, "no", 0)
    record_numerics(tmp_path, "no", 5)
    assert [a.start_step for a in read_numerics(tmp_path)] == [0, 5]
    assert [a.start_step for a in record_numerics(tmp_path, "no", 0)] == [0]
    assert read_numerics(tmp_path / "none") is None
    (tmp_path / NUMERICS_FILE).write_text('{"attempts": [{"attempt": 1}]}')
    with pytest.raises(UsageError, match=r"numerics\.json is not a numerics record"):
        read_numerics(tmp_path)
