"""Cross-fitted GLC: training on some tasks and scoring on others (`train_glc_on_store`'s task filter), and the
`glc_folds` gaze source that gives each episode the maps of the GLC that did not train on its task."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from gazereg.gaze.glc.checkpoint import save_glc
from gazereg.gaze.glc.data import write_synthetic_gaze_store
from gazereg.gaze.glc.evaluate import HoldoutSplit, holdout_split
from gazereg.gaze.glc.model import GLC, GLCConfig
from gazereg.gaze.priors import PriorsConfig, make_priors
from gazereg.gaze.sources import make_gaze_source, parse_source_params
from gazereg.gaze.sources.glc import GLCGaze, GLCParams
from gazereg.gaze.sources.glc_folds import GLCFoldsParams
from gazereg.gaze.sources.recorded import RecordedParams
from gazereg.runtime.errors import UsageError
from gazereg.training.glc_store import GLCStoreTrainConfig, task_split, train_glc_on_store

# a CPU-second-sized GLC (as tests/glc/test_glc_train.py's)
TINY = GLCConfig(
    crop_size=64,
    embed_dim=32,
    depth=3,
    q_stride_blocks=(1,),
    decoder_heads=(2, 1),
    decoder_kv_strides=((1, 4, 4), (1, 8, 8)),
    global_embed_convs=2,
)


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """Six episodes of three tasks (synthetic-0, -1, -2; episode i is task i % 3)."""
    return write_synthetic_gaze_store(
        tmp_path_factory.mktemp("folds") / "store", episodes=6, length=6, size=32, camera="cam", tasks=3
    )


@pytest.fixture(scope="module")
def folds(tmp_path_factory):
    """Two tiny GLC folders with different random weights."""
    root = tmp_path_factory.mktemp("glcs")
    out = []
    for seed in (0, 1):
        torch.manual_seed(seed)
        out.append(save_glc(GLC(TINY), TINY, root / f"fold{seed}"))
    return out


def test_a_task_filter_trains_on_those_tasks_and_can_score_on_others(store):
    base = GLCStoreTrainConfig(store=store.root, camera="cam", holdout_every=2)
    assert task_split(store, base) == holdout_split(store, 2)
    within = task_split(store, replace(base, tasks=("synthetic-0", "synthetic-1")))
    assert within == HoldoutSplit(train=(0, 1), heldout=(3, 4))  # per task every 2nd, task 2 left out
    across = task_split(
        store, replace(base, tasks=("synthetic-0",), heldout_tasks=("synthetic-1", "synthetic-2"))
    )
    assert across == HoldoutSplit(
        train=(0, 3), heldout=(1, 2)
    )  # the first of each held-out task's (every 2nd)
    with pytest.raises(UsageError, match=r"has no episodes of \['nope'\]"):
        task_split(store, replace(base, tasks=("nope",)))


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"heldout_tasks": ("a",)}, "--heldout-tasks needs --tasks"),
        ({"tasks": ("a",), "heldout_tasks": ("a",)}, "--heldout-tasks lists training tasks (--tasks): a"),
        ({"tasks": ("a", "a")}, "--tasks lists 'a' more than once"),
        (
            {"tasks": ("a",), "heldout_tasks": ("b",), "holdout": (1,)},
            "--holdout and --heldout-tasks: give one",
        ),
    ],
)
def test_bad_task_filters_are_refused_naming_them(changes, message):
    with pytest.raises(UsageError) as refused:
        GLCStoreTrainConfig(**changes)
    assert message in str(refused.value)


def test_a_glc_trained_on_one_task_is_scored_on_the_others(store, tmp_path):
    base = GLCStoreTrainConfig()
    cfg = replace(
        base,
        store=store.root,
        camera="cam",
        gaze=RecordedParams(),
        out=tmp_path / "glc",
        tasks=("synthetic-0",),
        heldout_tasks=("synthetic-1",),
        holdout_every=2,
        optim=replace(base.optim, steps=1, batch_size=2, warmup_steps=1),
    )
    result = train_glc_on_store(cfg)
    assert result.split == HoldoutSplit(train=(0, 3), heldout=(1,))
    assert result.eval_report["episodes"] == [1] and result.eval_report["train_episodes"] == [0, 3]


def test_each_episode_gets_the_maps_of_its_tasks_fold(store, folds, tmp_path):
    params = GLCFoldsParams(
        tasks=("synthetic-0", "synthetic-1", "synthetic-2"),
        checkpoints=(folds[0], folds[1], folds[1]),
        stride=1,
    )
    source = make_gaze_source(params)
    for i in store.indices():
        ep = store.read(i)
        fold = folds[0] if ep.task == "synthetic-0" else folds[1]
        expected, _ = GLCGaze(GLCParams(checkpoint=fold, stride=1))(ep, "cam", (8, 8))
        np.testing.assert_array_equal(source(ep, "cam", (8, 8))[0], expected)
    folds_record = source.describe()["folds"]
    assert [f["tasks"] for f in folds_record] == [["synthetic-0"], ["synthetic-1", "synthetic-2"]]
    assert folds_record[0]["checkpoint_sha256"] != folds_record[1]["checkpoint_sha256"]
    text = [
        "tasks=synthetic-0,synthetic-1,synthetic-2",
        f"checkpoints={folds[0]},{folds[1]},{folds[1]}",
        "stride=1",
    ]
    assert parse_source_params("glc_folds", text) == params  # `gazereg priors --source glc_folds`


def test_fold_priors_are_written_whole_and_refused_after_a_fold_changes(store, folds, tmp_path):
    import shutil

    copy = tmp_path / "store"
    shutil.copytree(store.root, copy)
    swap = [tmp_path / "a", tmp_path / "b"]
    for src, dst in zip(folds, swap, strict=True):
        shutil.copytree(src, dst)
    params = GLCFoldsParams(
        tasks=("synthetic-0", "synthetic-1", "synthetic-2"), checkpoints=(swap[0], swap[1], swap[1])
    )
    cfg = PriorsConfig(store=copy, source=params, name="glc", camera="cam", size=(8, 8))
    assert make_priors(cfg, progress=False) == "glc"
    assert (copy / "priors" / "glc" / "prior.json").exists()
    assert make_priors(cfg, progress=False) == "glc"  # a rerun with the same folds resumes
    shutil.copytree(folds[1], swap[0], dirs_exist_ok=True)  # fold 0 retrained (other weights)
    with pytest.raises(UsageError, match="were made with other settings"):
        make_priors(cfg, progress=False)


def test_an_episode_of_a_task_no_fold_predicts_is_an_error(store, folds):
    source = make_gaze_source(GLCFoldsParams(tasks=("synthetic-0",), checkpoints=(folds[0],)))
    with pytest.raises(UsageError, match="task 'synthetic-1' is predicted by no fold"):
        source(store.read(1), "cam", (8, 8))
    with pytest.raises(UsageError, match="2 tasks but 1 checkpoints"):
        GLCFoldsParams(tasks=("a", "b"), checkpoints=(Path("x"),))
    with pytest.raises(UsageError, match="listed more than once"):
        GLCFoldsParams(tasks=("a", "a"), checkpoints=(Path("x"), Path("y")))
