"""The baseline tuning's round 2 is derived from round 1's results by the rule its docstring states: every
one-factor change that beat `default` on validation, applied together; none before round 1 is complete."""

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def tune(tmp_path, monkeypatch, load_script):
    module = load_script("scripts/tune_baseline.py")
    monkeypatch.setattr(module, "DOCS", tmp_path)
    return module


def write(tune, name, reach, button):
    path = tune.result_path(name)
    path.parent.mkdir(parents=True, exist_ok=True)
    val = {
        "reach-v3": {"0": [reach, 25], "1": [0, 25]},
        "button-press-topdown-v3": {"0": [button, 25], "1": [0, 25]},
    }
    change, overrides = tune.CANDIDATES.get(name, ("x", []))
    path.write_text(json.dumps({"change": change, "overrides": overrides, "validation": val}))


def test_round_two_combines_every_change_that_beat_default(tune):
    scores = {"default": 30, "ema": 29, "lr5e-4": 38, "chunk8": 34, "wide": 30, "shift8": 31}
    for name in tune.CANDIDATES:
        write(tune, name, 0, scores.get(name, 10))
    change, overrides = tune.combined()
    assert change == "round 2: lr5e-4 + chunk8 + shift8"  # wide ties default: not a winner
    assert overrides == [
        *tune.CANDIDATES["lr5e-4"][1],
        *tune.CANDIDATES["chunk8"][1],
        *tune.CANDIDATES["shift8"][1],
    ]
    assert tune.command("combined", overrides)[-2:] == ["--out", "runs/tune/combined"]

    write(tune, "combined", 5, 40)
    assert "combined" in tune.all_candidates()
    assert tune.table().splitlines()[7].startswith("| combined | x | 45/100")  # best first


def test_round_two_needs_round_one_and_two_winners(tune):
    write(tune, "default", 1, 30)
    with pytest.raises(SystemExit, match="not run yet: ema, lr5e-4"):
        tune.combined()
    for name in tune.CANDIDATES:
        write(tune, name, 1, 31 if name == "ema" else 30)
    assert tune.combined() is None  # a single winner: it is the choice, nothing to combine


def test_the_tuned_recipe_is_the_chosen_candidates_and_the_paper_presets(load_script):
    from gazereg.experiment.config import PRESETS, paper, sweep
    from gazereg.runtime.config import config_diff, parse, to_dict
    from gazereg.training.config import tuned

    tune = load_script("scripts/tune_baseline.py", "tune_real")  # the committed docs/tuning results
    name = tune.chosen()
    assert name is not None, "tuning is not over: no chosen candidate in docs/tuning"
    cmd = tune.command(name, tune.all_candidates()[name][1])
    assert not [a for a in cmd if a.startswith("--image-size")]  # a recipe of training options only
    ran = parse(PRESETS, cmd[2:], prog="tune").train
    ignore = ("run_dir", "device")
    assert config_diff(to_dict(ran), to_dict(tuned()), ignore) == {}
    for preset in (paper, sweep):
        assert config_diff(to_dict(preset().train), to_dict(tuned()), ignore) == {}
    assert f"**Chosen recipe: {name}**" in (ROOT / "docs" / "tuning" / "baseline.md").read_text()


def test_a_candidate_is_recorded_from_its_finished_run_or_its_archive(tune):
    """A candidate's record reads its experiment through `read_run`: from an archive (evaluation records
    compressed) too. Validation successes per task and training seed are the run's clean outcomes."""
    from gazereg.experiment import read_run

    run = read_run(ROOT / "docs" / "records" / "paper-abl-b")
    result = tune.candidate_result(run, "default", "today's recipe", [])
    report = run.report
    val = result["validation"]
    assert set(val) == set(run.tasks) and all(set(seeds) == {"0", "1", "2"} for seeds in val.values())
    for task in run.tasks:
        cell = report["success"]["baseline"]["clean"]["per_task"][task]
        assert [sum(c[i] for c in val[task].values()) for i in (0, 1)] == [cell["successes"], cell["n"]]
    assert result["stage_seconds"] == report["stage_times_s"] and result["date"] == report["date"]
    assert result["command"].endswith("--out runs/tune/default")
