"""scripts/tune_photometric.py: the LIBERO photometric-augmentation protocol's commands, choice and table,
on archives made here (no LIBERO needed)."""

import dataclasses
import json
from pathlib import Path

import pytest

from gazereg.envs.libero.setup import SAMPLED_FROM
from gazereg.experiment import tuning
from gazereg.experiment.config import PRESETS
from gazereg.experiment.demos import demo_collections
from gazereg.experiment.tuning import built_config
from gazereg.runtime.config import config_diff, to_dict
from gazereg.runtime.errors import UsageError

ROOT = Path(__file__).resolve().parents[1]
TASKS = [f"libero_spatial/{i}" for i in range(10)]


@pytest.fixture
def tune(tmp_path, monkeypatch, load_script):
    module = load_script("scripts/tune_photometric.py")
    monkeypatch.setattr(module, "PROTOCOL", dataclasses.replace(module.PROTOCOL, root=tmp_path))
    monkeypatch.setattr(module, "PLACEMENTS", tmp_path / "placements.json")
    return module


def candidate(tune, name):
    return tune.PROTOCOL.candidate(name)


@pytest.fixture
def fake_archive(tune, candidate_archive):
    """`fake_archive(name, successes, dest=None, command=None)`: an archive of candidate `name` (its command's
    configuration unless `command`) whose validation episodes succeed `successes[condition]` times, over the
    tasks in order (10 clean setups per task, 5 under each perturbation)."""

    def make(name, successes, dest=None, command=None):
        episodes = []
        for cond, k in successes.items():
            per = 10 if cond == "clean" else 5
            episodes += [
                {"arm": "baseline@s0", "task": task, "condition": cond, "seed": SAMPLED_FROM + i, "length": 9,
                 "success": per * t + i < k}
                for t, task in enumerate(TASKS) for i in range(per)
            ]  # fmt: skip
        dest = tune.PROTOCOL.archive_path(name) if dest is None else dest
        return candidate_archive(dest, command or tune.PROTOCOL.command(candidate(tune, name)), episodes)

    return make


def test_the_candidates_differ_only_by_the_jitter_and_validate_on_sampled_placements(tune):
    configs = {
        c.name: to_dict(built_config(tuple(tune.PROTOCOL.command(c)))) for c in tune.PROTOCOL.candidates
    }
    for name, cfg in configs.items():
        assert cfg["env"] == "libero" and cfg["arms"] == ["baseline"] and cfg["demos_per_task"] == 25
        assert (
            cfg["eval"]["seed_start"] == SAMPLED_FROM
        )  # no fixed initial state: neither training nor evaluation
        assert cfg["eval"]["conditions"] == list(tune.CONDITIONS)
        jitter = (
            {}
            if name == "p0"
            else {k: [0.0, float(name[1:])] for k in ("brightness", "contrast", "saturation")}
        )
        assert config_diff(configs["p0"], cfg, ignore=("out",)) == {
            f"train.photometric.{k}": v for k, v in jitter.items()
        }


def test_the_candidates_hold_out_the_libero_presets_own_demonstrations_not_sampled_placements(tune):
    """The held-out demonstrations (alignment only) come from the preset's fixed states, where the expert
    succeeds, not from the validation range's sampled placements, where it solved none of four tasks."""
    preset = PRESETS["libero"]()
    want = demo_collections(preset, Path("p"))["heldout"].seed_base
    assert want < SAMPLED_FROM
    for cand in tune.PROTOCOL.candidates:
        cfg = built_config(tuple(tune.PROTOCOL.command(cand)))
        assert demo_collections(cfg, Path("p"))["heldout"].seed_base == want
        assert demo_collections(cfg, Path("p"))["train"] == demo_collections(preset, Path("p"))["train"]


def test_the_later_candidates_copy_the_first_ones_demonstrations_when_it_has_them(tune, tmp_path):
    p0, p25 = candidate(tune, "p0"), candidate(tune, "p0.25")
    assert tune.PROTOCOL.data_from(p0) == tune.PROTOCOL.data_from(p25) == []
    stages = tmp_path / "runs" / "tune-photometric" / "p0" / "stages"
    stages.mkdir(parents=True)
    (stages / "demos.json").write_text("{}")
    assert tune.PROTOCOL.data_from(p0) == [] and tune.PROTOCOL.data_from(p25) == [
        "--data-from",
        "runs/tune-photometric/p0",
    ]


def test_the_choice_pools_the_conditions_ties_to_the_weaker(tune, fake_archive):
    fake_archive("p0", {"clean": 60, "dim:0.7": 10, "gaussian_noise:0.5": 30})
    fake_archive("p0.25", {"clean": 55, "dim:0.7": 30, "gaussian_noise:0.5": 30})
    text = tune.table()
    assert "- not yet: p0.5 to run" in text
    assert (
        "| p0 | the preset: no augmentation | 60/100 = 0.60 | 10/50 = 0.20 | 30/50 = 0.60 | 100/200 = 0.50 |"
        in text
    )
    fake_archive("p0.5", {"clean": 45, "dim:0.7": 40, "gaussian_noise:0.5": 30})  # 115 ties p0.25
    text = tune.table()
    assert "- **p0.25**, brightness, contrast and saturation jitter 0.25: `--train.photometric.brightness 0.25 " \
        "--train.photometric.contrast 0.25 --train.photometric.saturation 0.25` in every arm's recipe" in text  # fmt: skip


def test_the_candidates_are_recounted_on_the_tasks_whose_placements_were_at_rest(tune, fake_archive):
    """With the placement check of the env the candidates ran on, a second table counts only the tasks whose
    validation placements were all at rest; without the file there is none."""
    fake_archive("p0", {"clean": 60, "dim:0.7": 10, "gaussian_noise:0.5": 30})
    assert "Recounted" not in tune.table()
    unsettled = {"libero_spatial/3": 2, "libero_spatial/4": 10}
    check = {"tasks": [{"task": t, "sampled": {"unsettled": unsettled.get(t, 0)}} for t in TASKS]}
    tune.PLACEMENTS.write_text(json.dumps(check))
    text = tune.table()
    assert (
        "(libero_spatial/0, libero_spatial/1, libero_spatial/2, libero_spatial/5, libero_spatial/6," in text
    )
    # clean: the first 60 setups succeed (tasks 0..5), of which tasks 0, 1, 2 and 5 are counted
    assert "| p0 | 40/80 = 0.50 | 10/40 = 0.25 | 20/40 = 0.50 | 70/160 = 0.44 |" in text


def test_an_archive_of_another_command_is_refused(tune, fake_archive):
    fake_archive("p0.5", {"clean": 1}, command=tune.PROTOCOL.command(candidate(tune, "p0")))
    with pytest.raises(UsageError, match=r"tune-photometric/p0\.5 holds a run with another configuration"):
        tune.table()


def test_a_candidate_is_run_archived_and_recorded(tune, monkeypatch, fake_archive):
    ran = []

    def fake_run(command, root):
        ran.append(command)
        fake_archive(
            "p0",
            {"clean": 70, "dim:0.7": 20, "gaussian_noise:0.5": 10},
            dest=root / "runs" / "tune-photometric" / "p0",
        )

    monkeypatch.setattr(tuning, "run_experiment", fake_run)
    assert tune.main(["--only", "p0"]) == 0
    assert ran == [tune.PROTOCOL.command(candidate(tune, "p0"))]
    record = json.loads(tune.PROTOCOL.result_path("p0").read_text())
    assert record["command"].endswith("--out runs/tune-photometric/p0")
    by_cond = record["validation_by_condition"]
    assert sum(c[0] for seeds in by_cond["dim:0.7"].values() for c in seeds.values()) == 20
    assert (
        "| 70/100 = 0.70 | 20/50 = 0.40 | 10/50 = 0.20 | 100/200 = 0.50 |"
        in tune.PROTOCOL.table_path.read_text()
    )


def test_the_committed_table_is_the_archives(load_script):
    assert (
        load_script("scripts/tune_photometric.py", "tune_photometric_real").table()
        == (ROOT / "docs" / "tuning" / "photometric.md").read_text()
    )


def test_the_libero_presets_train_with_the_chosen_augmentation(load_script):
    """The protocol's choice is the recipe every LIBERO suite's arms train with (the presets, not a flag)."""
    tune = load_script("scripts/tune_photometric.py", "tune_photometric_chosen")
    cand = tune.chosen()
    assert cand is not None and cand.name in (ROOT / "docs" / "tuning" / "photometric.md").read_text()
    for preset in ("libero", "libero_object", "libero_goal", "libero_10"):
        diff = tune.PROTOCOL.recipe_diff(cand, PRESETS[preset]())
        assert not [k for k in diff if k.startswith("train.photometric.")], (preset, diff)
    assert tune.PROTOCOL.recipe_diff(cand, PRESETS["libero"]()) == {}
