"""Checkpoint files (issue 33): the umask's mode, equal bytes for equal states, a damaged file named in one line,
a full disk while saving named with the previous checkpoint kept."""

import dataclasses
import errno
import hashlib
import os
from pathlib import Path

import pytest
import torch
from safetensors import SafetensorError

from gazereg.cli import main as cli_main
from gazereg.policies import load_policy
from gazereg.runtime.io import DamagedFile, load_safetensors, save_safetensors
from gazereg.training import checkpoint as checkpoint_module
from gazereg.training.checkpoint import (
    CheckpointNotSaved,
    DamagedCheckpoint,
    list_checkpoints,
    read_checkpoint,
)
from gazereg.training.config import smoke
from gazereg.training.loop import train
from gazereg.training.setup import build


def cfg(store, run_dir, **kw):
    base = smoke()
    data = dataclasses.replace(base.data, store=Path(store.root), val_fraction=0.25)
    return dataclasses.replace(base, run_dir=Path(run_dir), data=data, **kw)


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def digests(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


# ----- item 4: modes ------------------------------------------------------------------------------------------
def test_checkpoint_files_get_the_mode_of_an_ordinary_write(tiny_store, tmp_path, umask_022):
    run = tmp_path / "run"
    train(cfg(tiny_store, run, steps=2, save_every=2, eval_every=2, log_every=1))
    ckpt = run / "checkpoints" / "step_000002"
    files = [p for p in ckpt.rglob("*") if p.is_file()]
    assert {p.name for p in files} >= {"model.safetensors", "optimizer.safetensors", "rng.safetensors"}
    wrong = {str(p.relative_to(ckpt)): oct(p.stat().st_mode & 0o777) for p in files}
    wrong = {k: v for k, v in wrong.items() if v != oct(0o644)}
    assert wrong == {}  # safetensors' own writer makes 0600 files
    assert all(p.stat().st_mode & 0o777 == 0o755 for p in ckpt.rglob("*") if p.is_dir())
    os.umask(0o027)
    save_safetensors({"a": torch.zeros(2)}, tmp_path / "x.safetensors")
    assert (tmp_path / "x.safetensors").stat().st_mode & 0o777 == 0o640


# ----- item 5: bytes ------------------------------------------------------------------------------------------
def test_equal_weights_give_byte_identical_files(tiny_store, tmp_path):
    policy = build(cfg(tiny_store, tmp_path / "unused")).policy
    outs = set()
    for k in range(8):  # the library writes its metadata in hash order, which changes from map to map
        folder = tmp_path / f"p{k}"
        folder.mkdir()
        policy.write_pretrained(folder)
        outs.add((folder / "model.safetensors").read_bytes())
    assert len(outs) == 1
    a, b = {"w": torch.ones(3), "b": torch.zeros(2, dtype=torch.int64)}, tmp_path / "a.safetensors"
    save_safetensors(a, b, metadata={"z": "1", "a": "2"})
    save_safetensors(dict(reversed(a.items())), tmp_path / "b.safetensors", metadata={"a": "2", "z": "1"})
    assert b.read_bytes() == (tmp_path / "b.safetensors").read_bytes()
    assert all(torch.equal(load_safetensors(b)[k], v) for k, v in a.items())


def test_identical_runs_write_identical_checkpoints(tiny_store, tmp_path):
    kw = dict(steps=2, save_every=2, eval_every=2, log_every=1)
    train(cfg(tiny_store, tmp_path / "a", **kw))
    train(cfg(tiny_store, tmp_path / "b", **kw))
    a, b = (digests(tmp_path / r / "checkpoints" / "step_000002") for r in "ab")
    assert len(a) >= 8 and a.pop("training_state/state.json") != b.pop("training_state/state.json")
    assert a == b  # every file but state.json, which records the run folder
    sa, sb = (read_checkpoint(tmp_path / r / "checkpoints" / "step_000002").state for r in "ab")
    assert {**sa, "config": {**sa["config"], "run_dir": ""}} == {
        **sb,
        "config": {**sb["config"], "run_dir": ""},
    }


# ----- item 6: damaged files and a full disk ------------------------------------------------------------------
def test_a_damaged_model_file_is_named_in_one_line(tiny_store, tmp_path, capsys):
    run = tmp_path / "run"
    train(cfg(tiny_store, run, steps=2, save_every=2, eval_every=2, log_every=1))
    ckpt = run / "checkpoints" / "step_000002"
    model = ckpt / "model.safetensors"
    model.write_bytes(model.read_bytes()[: model.stat().st_size // 2])  # a truncated copy
    with pytest.raises(DamagedFile) as e:
        load_policy(ckpt)
    assert str(e.value) == (
        f"{model} is damaged (safetensors header: incomplete metadata, file not fully covered); "
        "re-save or retrain"
    )
    with pytest.raises(DamagedCheckpoint, match=rf"checkpoint file {model} cannot be read: it is damaged"):
        read_checkpoint(ckpt)
    argv = [
        "eval",
        "--checkpoints",
        f"a={ckpt}",
        "--episodes",
        "1",
        "--workers",
        "1",
        "--out",
        str(tmp_path / "e"),
    ]
    assert cli_main(argv) == 2
    last = capsys.readouterr().err.splitlines()[-1]  # after the progress bar's line
    assert (
        last.startswith(f"gazereg eval: error: {model} is damaged (safetensors header: ")
        and "re-save" in last
    )


@pytest.mark.parametrize(
    "error",
    [
        SafetensorError(
            'Error while serializing: IoError(Os { code: 28, kind: StorageFull, message: "No space left on '
            'device" })'
        ),
        OSError(errno.ENOSPC, "No space left on device"),
    ],
    ids=["safetensors", "oserror"],
)
def test_a_full_disk_while_saving_keeps_the_previous_checkpoint(tiny_store, tmp_path, monkeypatch, error):
    run = tmp_path / "run"
    c = cfg(tiny_store, run, steps=4, save_every=2, eval_every=2, log_every=1)
    real = checkpoint_module.save_tensors_json

    def full_at_step_4(directory, name, sd):
        if name == "optimizer" and any(
            p.name.startswith(".step_000004") for p in run.joinpath("checkpoints").iterdir()
        ):
            raise error
        return real(directory, name, sd)

    monkeypatch.setattr(checkpoint_module, "save_tensors_json", full_at_step_4)
    with pytest.raises(CheckpointNotSaved) as e:
        train(c)
    assert str(e.value) == (
        f"no space left on {run / 'checkpoints'} while saving checkpoint step_000004; the previous checkpoint "
        "(step_000002) is kept. Free space and resume with --resume"
    )
    assert [p.name for _, p in list_checkpoints(run)] == ["step_000002"]
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["step_000002"]  # no temporary left
    before = read_checkpoint(run / "checkpoints" / "step_000002")
    assert before.state["step"] == 2
