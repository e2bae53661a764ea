"""ML45's split as metaworld defines it, an expert and an instruction for each of its 50 tasks, and the setup
seed ranges: pretraining's are disjoint from each other and from every seed another command's presets use."""

from __future__ import annotations

from pathlib import Path

import pytest

from gazereg.envs.collect_config import PRESETS as COLLECT_PRESETS
from gazereg.envs.collect_config import collect_seeds
from gazereg.envs.metaworld.instructions import INSTRUCTIONS
from gazereg.envs.metaworld.ml45 import BenchmarkSplit, ml45_split
from gazereg.envs.metaworld.setups import EXPERIMENTS, PRETRAIN_DEMOS, PRETRAIN_EVAL, RANGES, SetupRange
from gazereg.evaluation.config import presets as eval_presets
from gazereg.experiment.config import PRESETS as EXPERIMENT_PRESETS
from gazereg.experiment.demos import demo_collections
from gazereg.experiment.pretrain_config import PRESETS as PRETRAIN_PRESETS
from gazereg.runtime.errors import UsageError

HELD_OUT = {"bin-picking-v3", "box-close-v3", "door-lock-v3", "door-unlock-v3", "hand-insert-v3"}


@pytest.fixture(scope="module")
def split() -> BenchmarkSplit:
    pytest.importorskip("metaworld")
    return ml45_split()


def test_ml45_held_out_five_are_the_issues_and_the_45_train_tasks_are_disjoint(split):
    assert set(split.test) == HELD_OUT and len(split.test) == 5
    assert len(split.train) == 45 and len(set(split.train)) == 45
    assert not set(split.train) & HELD_OUT
    assert split.tasks("all") == split.train + split.test
    assert all(t.endswith("-v3") for t in split.all)


def test_every_ml45_task_has_a_scripted_expert_and_its_own_instruction(split):
    from metaworld.policies import ENV_POLICY_MAP

    assert [t for t in split.all if t not in ENV_POLICY_MAP] == []
    assert [t for t in split.all if t not in INSTRUCTIONS] == []
    assert len({INSTRUCTIONS[t] for t in split.all}) == 50


def test_a_split_refuses_overlap_and_repeats():
    with pytest.raises(ValueError, match="both training and held-out"):
        BenchmarkSplit("x", ("a", "b"), ("b",))
    with pytest.raises(ValueError, match="more than once"):
        BenchmarkSplit("x", ("a", "a"), ("b",))
    with pytest.raises(ValueError, match="empty"):
        BenchmarkSplit("x", ("a",), ())


def test_named_ranges_are_pairwise_disjoint():
    for i, a in enumerate(RANGES):
        for b in RANGES[i + 1 :]:
            assert not a.overlaps(b), (a.name, b.name)
    assert SetupRange("a", 0, 10, "").overlaps(range(9, 12))
    assert not SetupRange("a", 0, 10, "").overlaps(range(10, 12))


def other_commands_seeds() -> dict[str, range]:
    """Every setup-seed range the presets of collect, eval and experiment use (per task)."""
    used = {f"collect:{n}": collect_seeds(p()) for n, p in COLLECT_PRESETS.items()}
    for name, preset in eval_presets().items():
        cfg = preset()
        used.update({f"eval:{name}:{c}": cfg.seeds(c) for c in cfg.conditions})
    for name, preset in EXPERIMENT_PRESETS.items():
        cfg = preset()
        for store, ccfg in demo_collections(cfg, Path("x")).items():
            used[f"experiment:{name}:{store}"] = collect_seeds(ccfg)
        used.update({f"experiment:{name}:eval:{c}": cfg.eval.seeds(c) for c in cfg.eval.conditions})
    used["tune_baseline:validation"] = range(1300, 1325)  # scripts/tune_baseline.py's --eval.seed-start 1300
    return used


def test_other_commands_stay_in_their_range_and_off_pretrainings():
    used = other_commands_seeds()
    assert len(used) > 20
    outside = {k: r for k, r in used.items() if not EXPERIMENTS.contains(r)}
    assert outside == {}
    assert [k for k, r in used.items() if PRETRAIN_DEMOS.overlaps(r) or PRETRAIN_EVAL.overlaps(r)] == []


def test_pretraining_presets_use_their_own_ranges():
    pytest.importorskip("metaworld")
    for name, preset in PRETRAIN_PRESETS.items():
        cfg = preset()
        assert PRETRAIN_DEMOS.contains(cfg.demo_seeds), name
        assert PRETRAIN_EVAL.contains(cfg.eval_seeds), name


def test_a_range_refuses_seeds_outside_it_in_one_line():
    PRETRAIN_EVAL.require(range(101_000, 101_050), "--eval-episodes 50")
    with pytest.raises(UsageError, match=r"--eval-episodes 1001: setup seeds 101000..102000 leave"):
        PRETRAIN_EVAL.require(range(101_000, 102_001), "--eval-episodes 1001")
