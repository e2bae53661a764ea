"""`gazereg glc train` / `eval` end to end on a tiny synthetic store, and the data helpers they use."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from gazereg.cli import glc_main
from gazereg.gaze.glc.cli import GLCEvalCommand
from gazereg.gaze.glc.data import (
    StoreClipDataset,
    episode_gaze_points,
    fixation_mask,
    write_synthetic_gaze_store,
)
from gazereg.gaze.glc.evaluate import HoldoutSplit, holdout_split
from gazereg.runtime.errors import UsageError
from gazereg.training.glc import GLCTrainConfig
from gazereg.training.glc_store import GLCStoreTrainConfig


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    return write_synthetic_gaze_store(
        tmp_path_factory.mktemp("glc") / "store", episodes=4, length=10, size=32, camera="cam", tasks=1
    )


def test_split_is_deterministic_and_per_task(tmp_path):
    s = write_synthetic_gaze_store(tmp_path / "s", episodes=6, length=2, size=8, camera="cam", tasks=2)
    assert holdout_split(s, holdout_every=3) == HoldoutSplit(train=(0, 1, 2, 3), heldout=(4, 5))
    assert holdout_split(s, holdout=(1,)).to_dict() == {"train": [0, 2, 3, 4, 5], "heldout": [1]}
    with pytest.raises(UsageError, match=r"--holdout: held-out episodes \[9\] are not in"):
        holdout_split(s, holdout=(9,))


def test_dataset_items_and_gaze(store):
    ds = StoreClipDataset(store, [0, 1], "cam", crop_size=96, num_frames=8, stride=2, hop=2)
    assert len(ds) == 10
    clip, gaze, valid = ds[1]  # anchor frame 2 of episode 0
    assert clip.shape == (3, 8, 96, 96) and clip.dtype.is_floating_point is False
    pts, ok = episode_gaze_points(store.read(0), "cam", "recorded")
    np.testing.assert_allclose(
        gaze[4].numpy(), pts[2], atol=1e-6
    )  # square frames: crop coords = frame coords
    assert valid.all() and ok.all()
    with pytest.raises(KeyError, match="no recorded gaze"):
        episode_gaze_points(store.read(0), "other", "recorded")
    m = fixation_mask(np.array([[0.1, 0.1], [0.1, 0.12], [0.5, 0.5]]), np.ones(3, bool), 0.05)
    assert m.tolist() == [True, True, False]


def test_train_and_eval_commands_write_their_outputs(store, tmp_path, capsys):
    out = tmp_path / "run"
    args = [
        "train",
        "--store",
        str(store.root),
        "--camera",
        "cam",
        "--gaze-source",
        "recorded",
        "--out",
        str(out),
        "--holdout-every",
        "2",
        "--optim.steps",
        "2",
        "--optim.batch-size",
        "2",
        "--optim.warmup-steps",
        "1",
    ]
    assert glc_main(args) == 0
    for name in (
        "final/model.safetensors",
        "final/config.json",
        "final/glc_train.json",
        "run.json",
        "eval.json",
        "train_log.jsonl",
    ):
        assert (out / name).exists(), name
    info = json.loads((out / "final" / "glc_train.json").read_text())
    assert info["split"] == {"train": [0, 2], "heldout": [1, 3]} and info["steps"] == 2
    rep = json.loads((out / "eval.json").read_text())
    assert set(rep["scores"]["all_valid"]) == {"glc", "centre_prior", "uniform"}
    assert rep["episodes"] == [1, 3] and rep["scores"]["all_valid"]["glc"]["n_frames"] == 20

    report = tmp_path / "eval2.json"
    assert (
        glc_main(
            [
                "eval",
                "--store",
                str(store.root),
                "--checkpoint",
                str(out),
                "--mode",
                "centre",
                "--fixation-threshold",
                "0.05",
                "--out",
                str(report),
            ]
        )
        == 0
    )
    rep2 = json.loads(report.read_text())
    assert rep2["source"]["mode"] == "centre" and rep2["episodes"] == [1, 3] and "fixation" in rep2["scores"]
    for sc in rep2["scores"]["all_valid"].values():
        assert 0 <= sc["f1"] <= 1 and 0 <= sc["recall"] <= 1
    assert "centre_prior" in capsys.readouterr().out

    # episodes of another store (held-out tasks): its centre prior is fitted on the GLC's training store
    # (--centre-from), the same as on that store itself; without it the store has no training episodes
    other = write_synthetic_gaze_store(
        tmp_path / "other", episodes=2, length=10, size=32, camera="cam", seed=5
    )
    cross = ["eval", "--store", str(other.root), "--checkpoint", str(out), "--episodes", "0", "1"]
    assert glc_main([*cross, "--centre-from", str(store.root), "--out", str(tmp_path / "cross.json")]) == 0
    fitted = json.loads((tmp_path / "cross.json").read_text())["centre_prior"]
    assert fitted["fitted_on"] == {"store": str(store.root), "episodes": 2}
    assert (
        fitted["centre"] == rep["centre_prior"]["centre"] and fitted["sigma"] == rep["centre_prior"]["sigma"]
    )
    assert f"centre prior fitted on 2 training episodes of {store.root}" in capsys.readouterr().out
    assert glc_main([*cross, "--out", str(tmp_path / "default.json")]) == 0
    assert json.loads((tmp_path / "default.json").read_text())["centre_prior"]["fitted_on"] is None
    assert "centre prior: the default (no training episodes" in capsys.readouterr().out
    from gazereg import cli

    assert cli.main(["glc", *cross, "--centre-from", str(tmp_path / "nowhere")]) == 2
    assert f"--centre-from: {tmp_path / 'nowhere'} is not an episode store" in capsys.readouterr().err


def test_cli_usage_and_errors(tmp_path, store, capsys):
    assert glc_main([]) == 0
    assert capsys.readouterr().out.startswith("usage: gazereg glc <train|eval> [--preset NAME] [options]\n")
    assert glc_main(["bogus"]) == 2
    assert "gazereg glc: unknown subcommand 'bogus'" in capsys.readouterr().err
    with pytest.raises(FileNotFoundError):
        glc_main(["eval", "--store", str(store.root), "--checkpoint", str(tmp_path / "missing")])


def test_gaze_points_from_a_trace_or_from_map_peaks(store):
    from types import SimpleNamespace

    ep = store.read(0)
    T = ep.length
    uv = np.tile(np.array([[0.25, 0.75]], np.float32), (T, 1))
    ok = np.ones(T, bool)
    ok[3] = False

    class Traced:  # like the visuomotor source
        def trace(self, episode, camera):
            return SimpleNamespace(uv=uv, valid=ok)

    class MapsOnly:
        def __call__(self, episode, camera, size):
            maps = np.zeros((T, *size), np.float32)
            maps[:, 48, 16] = 1.0  # cell centre (16.5/64, 48.5/64)
            return maps, np.ones(T, bool)

    pts, valid = episode_gaze_points(ep, "cam", Traced())
    assert valid.tolist() == ok.tolist() and np.isnan(pts[3]).all() and np.allclose(pts[0], [0.25, 0.75])
    pts, valid = episode_gaze_points(ep, "cam", MapsOnly())
    assert valid.all() and np.allclose(pts[0], [16.5 / 64, 48.5 / 64])


def test_library_training_returns_a_typed_result(store, tmp_path):
    from dataclasses import replace

    from gazereg.gaze.sources.recorded import RecordedParams
    from gazereg.training.glc_store import GLCStoreTrainConfig, train_glc_on_store

    base = GLCStoreTrainConfig()
    cfg = replace(
        base,
        store=store.root,
        camera="cam",
        gaze=RecordedParams(),
        out=tmp_path / "lib",
        holdout=(3,),
        optim=replace(base.optim, steps=1, batch_size=2, warmup_steps=1),
        evaluate=False,
    )
    done = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True
    )
    stale = (
        tmp_path / "lib" / "checkpoints" / f".step_000001.{int(done.stdout)}.abcd1234.tmp"
    )  # a killed run's
    stale.mkdir(parents=True)
    result = train_glc_on_store(cfg)
    assert not stale.exists()  # swept at the start
    assert result.steps == 1 and result.final == tmp_path / "lib" / "final"
    assert result.split == HoldoutSplit(train=(0, 1, 2), heldout=(3,))
    assert result.eval_path is None and result.eval_report is None and result.first_loss is not None
    run = json.loads((tmp_path / "lib" / "run.json").read_text())
    assert run["gaze_source"] == "recorded" and run["gaze_params"] == []
    assert train_glc_on_store(cfg).first_loss is None  # finished: a second call resumes and trains nothing


def test_gaze_params_are_recorded_as_text_that_reads_back():
    from gazereg.gaze.sources import parse_source_params
    from gazereg.gaze.sources.visuomotor import VisuomotorParams
    from gazereg.training.glc_store import source_params_text

    assert source_params_text(VisuomotorParams()) == ()
    params = VisuomotorParams(lead_time_s=0.4, targets=("a", "b"), fps=None, seed=3)
    text = source_params_text(params)
    assert text == ("lead_time_s=0.4", 'targets=["a", "b"]', "seed=3")
    assert parse_source_params("visuomotor", text) == params


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: GLCTrainConfig(steps=0), "--optim.steps must be an integer >= 1, got 0"),
        (lambda: GLCTrainConfig(batch_size=0), "--optim.batch-size must be"),
        (lambda: GLCTrainConfig(lr=float("nan")), "--optim.lr must be a finite number > 0, got nan"),
        (lambda: GLCTrainConfig(warmup_steps=-1), "--optim.warmup-steps must be"),
        (lambda: GLCTrainConfig(temperature=0), "--optim.temperature must be"),
        (lambda: GLCTrainConfig(checkpoint_every=0), "--optim.checkpoint-every must be"),
        (lambda: GLCTrainConfig(keep_last=0), "--optim.keep-last must be"),
        (lambda: GLCStoreTrainConfig(stride=0), "--stride must be"),
        (lambda: GLCStoreTrainConfig(clip_hop=0), "--clip-hop must be"),
        (lambda: GLCStoreTrainConfig(holdout_every=1), "--holdout-every must be an integer >= 2, got 1"),
        (lambda: GLCStoreTrainConfig(config="huge"), "--config must be one of official, small, got 'huge'"),
        (lambda: GLCEvalCommand(hop=0), "--hop must be"),
        (lambda: GLCEvalCommand(batch_size=0), "--batch-size must be"),
        (lambda: GLCEvalCommand(stride=0), "--stride must be"),
    ],
)
def test_bad_glc_settings_are_refused_when_built(make, message):
    with pytest.raises(UsageError) as refused:
        make()
    assert message in str(refused.value)


def test_eval_refuses_episodes_the_store_lacks(store, tmp_path, capsys):
    from gazereg import cli

    ckpt = tmp_path / "glc.pyth"
    ckpt.write_bytes(b"")
    args = ["glc", "eval", "--store", str(store.root), "--checkpoint", str(ckpt), "--episodes", "0", "77"]
    assert cli.main(args) == 2
    assert "--episodes: episodes [77] are not in" in capsys.readouterr().err


def test_evaluation_reads_a_store_larger_than_the_open_file_limit(tmp_path):
    """Every memory-mapped episode holds open files: an evaluation that kept the episodes it read (held out
    and training) ran out of file descriptors on a 2,250-episode store. Here 60 episodes (five files each)
    under a limit of 128 open files."""
    import resource

    big = write_synthetic_gaze_store(tmp_path / "big", episodes=60, length=4, size=16, camera="cam", tasks=2)
    assert len(list((big.root / "episodes" / "ep_000000").glob("*.npy"))) * 60 > 128
    args = ["train", "--store", str(big.root), "--camera", "cam", "--gaze-source", "recorded"]
    args += ["--out", str(tmp_path / "run"), "--holdout-every", "2", "--optim.steps", "1"]
    args += ["--optim.batch-size", "2", "--optim.warmup-steps", "1"]
    code = f"import sys; from gazereg.cli import glc_main; sys.exit(glc_main({args!r}))"

    def limit_files():
        resource.setrlimit(resource.RLIMIT_NOFILE, (128, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))

    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, preexec_fn=limit_files, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    rep = json.loads((tmp_path / "run" / "eval.json").read_text())
    assert len(rep["episodes"]) == 30 and rep["scores"]["all_valid"]["glc"]["n_frames"] == 120
    assert "held out: 30 episodes, " in done.stderr  # a count, not 30 indices
