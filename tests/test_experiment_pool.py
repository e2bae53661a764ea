"""`gazereg pool`: one seed per folder (and an arm added later), then one report, the same as the experiment
run with every seed and arm; the same from the folders' archives (`gazereg archive`) once they are gone."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from gazereg import cli
from gazereg.experiment.reuse import check_source
from gazereg.experiment.runner import Experiment
from gazereg.experiment.tuning import built_config

pytestmark = pytest.mark.sim

SMALL = ["--preset", "smoke", "--eval.conditions", "clean", "--parallel", "1"]
ARMS = ["--arms", "baseline", "gaze", "perturbed"]


def _experiment(out, seeds, arms=("baseline", "gaze"), more=()):
    seeds = ["--train-seeds", *map(str, seeds)]
    return cli.main(["experiment", *SMALL, "--arms", *arms, *seeds, "--out", str(out), *more])


def test_pooled_folders_report_what_one_run_of_every_seed_and_arm_reports(tmp_path, capsys):
    s0 = ["--data-from", str(tmp_path / "s0")]
    assert _experiment(tmp_path / "s0", [0]) == 0
    assert _experiment(tmp_path / "s1", [1], more=s0) == 0  # s0's demos and priors
    assert _experiment(tmp_path / "perturbed", [0, 1], ["perturbed"], s0) == 0  # s0's demos; its own priors
    for folder, stage, copied in (
        ("s1", "priors", True),
        ("perturbed", "demos", True),
        ("perturbed", "priors", False),
    ):
        record = json.loads((tmp_path / folder / "stages" / f"{stage}.json").read_text())
        assert (record.get("copied_from") == str(tmp_path / "s0")) == copied, (folder, stage)
        assert (record["seconds"] == 0.0) == copied, (folder, stage)
    capsys.readouterr()  # refused, one line: other demonstrations
    assert _experiment(tmp_path / "p", [2], more=["--heldout-per-task", "2", *s0]) == 2
    assert "heldout_per_task: 1 -> 2" in capsys.readouterr().err
    recipe = ("gazereg", "experiment", *SMALL, "--arms", "baseline", "gaze", "--train.steps", "13")
    recipe_cfg = built_config((*recipe, "--out", str(tmp_path / "r")))
    # another training recipe: the same demonstrations and priors, so both stages are copied
    records, missing = check_source(Experiment(recipe_cfg, "smoke"), tmp_path / "s0")
    assert set(records) == {"demos", "priors"} and missing == []
    assert (
        _experiment(tmp_path / "s0", [0], more=["--data-from", str(tmp_path / "s1")]) == 0
    )  # nothing copied
    assert _experiment(tmp_path / "both", [0, 1], ARMS[1:]) == 0
    runs = ["--runs", *(str(tmp_path / f) for f in ("s0", "s1", "perturbed"))]
    pooled = tmp_path / "pooled"
    assert cli.main(["pool", *SMALL, *ARMS, "--train-seeds", "0", "1", *runs, "--out", str(pooled)]) == 0
    a = json.loads((pooled / "report.json").read_text())
    b = json.loads((tmp_path / "both" / "report.json").read_text())
    for key in ("success", "paired", "per_seed", "distance", "verdict", "alignment", "val_loss", "demos"):
        assert a[key] == b[key], key
    assert a["train"]["seeds"] == [0, 1] and a["pooled_from"] == runs[1:]
    assert a["wall_time_s"] == pytest.approx(
        sum(
            json.loads((tmp_path / s / "report.json").read_text())["wall_time_s"]
            for s in ("s0", "s1", "perturbed")
        )
    )
    from matplotlib.image import imread

    # one attention figure over every arm: s0's (baseline, gaze) above perturbed's; s1 shows no new arm
    heights = {f: imread(tmp_path / f / "figures" / "attention.png").shape[0] for f in ("s0", "perturbed")}
    assert imread(pooled / a["figures"]["attention"]).shape[0] == heights["s0"] + heights["perturbed"]
    assert (
        f"summed over 3 runs pooled by `gazereg pool`: {', '.join(runs[1:])}."
        in (pooled / "report.md").read_text()
    )
    from gazereg.report import results_block

    # the options that differ from the preset, what was measured only (not --parallel, an execution key)
    assert a["pooled_flags"] == ["--eval.conditions", "clean"]
    flags = f"--eval.conditions clean {' '.join(ARMS)}"
    command = f"gazereg pool --preset smoke {flags} --train-seeds 0 1 --runs {' '.join(runs[1:])}"
    assert f"(`{command}`)" in results_block(a, "x.png")  # the command that pools them again

    capsys.readouterr()  # refused, one line each: a run missing, runs twice, an arm not asked, another config
    unnamed = [*SMALL[2:], *ARMS, "--train-seeds", "0", "1", *runs, "--out", str(pooled)]
    assert cli.main(["pool", *unnamed]) == 2  # no default: the preset the runs were made with is asked for
    assert "--preset NAME is required" in capsys.readouterr().err
    seeds3 = [*ARMS, "--train-seeds", "0", "1", "2"]
    assert cli.main(["pool", *SMALL, *seeds3, *runs, "--out", str(pooled)]) == 2
    assert "missing baseline@s2, gaze@s2, perturbed@s2, not asked for none" in capsys.readouterr().err
    twice = [*runs, str(tmp_path / "both")]
    assert cli.main(["pool", *SMALL, *ARMS, "--train-seeds", "0", "1", *twice, "--out", str(pooled)]) == 2
    assert "overlap" in capsys.readouterr().err
    assert cli.main(["pool", *SMALL, "--arms", "baseline", "gaze", *runs, "--out", str(pooled)]) == 2
    assert "trained ['perturbed'], not in --arms" in capsys.readouterr().err
    changed = [*SMALL, *ARMS, "--train.steps", "13", "--train-seeds", "0", "1", *runs, "--out", str(pooled)]
    assert cli.main(["pool", *changed]) == 2
    assert "train.steps: 12 -> 13" in capsys.readouterr().err
    assert cli.main(["pool", *SMALL, *ARMS, *runs, "--out", str(pooled)]) == 2  # the preset's seeds: 0
    assert "missing none, not asked for baseline@s1, gaze@s1, perturbed@s1" in capsys.readouterr().err
    assert (
        cli.main(["pool", *SMALL, *ARMS, "--train-seeds", "0", "1", *runs, "--out", str(tmp_path / "s0")])
        == 2
    )
    assert "one of the pooled folders" in capsys.readouterr().err
    _pooled_archives_report_what_the_folders_do(tmp_path, ["s0", "s1", "perturbed"], pooled, capsys)


def _pooled_archives_report_what_the_folders_do(tmp_path, folders, pooled, capsys):
    """`gazereg archive` keeps what `pool` reads and no data: once the folders are gone (a fresh machine),
    their archives pool into the same report."""
    kept = [tmp_path / "kept" / f for f in folders]
    for folder, archive in zip(folders, kept):
        assert cli.main(["archive", str(tmp_path / folder), "--out", str(archive)]) == 0
    files = [p for p in (tmp_path / "kept").rglob("*") if p.is_file()]
    assert {p.suffix for p in files} == {".json", ".md", ".png", ".gz"}, sorted(map(str, files))
    again = tmp_path / "again"  # an archive of an archive is the archive
    assert cli.main(["archive", str(kept[0]), "--out", str(again)]) == 0
    assert sorted(p.relative_to(again) for p in again.rglob("*")) == sorted(
        p.relative_to(kept[0]) for p in kept[0].rglob("*")
    )
    shutil.copytree(again, tmp_path / "cut")
    (tmp_path / "cut" / "stages" / "eval.json").unlink()
    capsys.readouterr()  # refused, one line each: an unfinished folder, an archive inside its folder
    assert cli.main(["archive", str(tmp_path / "cut"), "--out", str(tmp_path / "k2")]) == 2
    assert "has not finished its eval stage" in capsys.readouterr().err
    assert cli.main(["archive", str(tmp_path / "s0"), "--out", str(tmp_path / "s0" / "kept")]) == 2
    assert "inside the run folder" in capsys.readouterr().err
    kept[0] = again
    for folder in folders:
        shutil.rmtree(tmp_path / folder)
    out = tmp_path / "pooled-kept"
    args = ["pool", *SMALL, *ARMS, "--train-seeds", "0", "1", "--runs", *map(str, kept), "--out", str(out)]
    assert cli.main(args) == 0
    a, b = (json.loads((d / "report.json").read_text()) for d in (pooled, out))
    for key in ("success", "paired", "per_seed", "distance", "verdict", "alignment", "val_loss", "demos"):
        assert a[key] == b[key], key
    assert (a["date"], a["wall_time_s"]) == (b["date"], b["wall_time_s"])
    assert (out / b["figures"]["convergence"]).stat().st_size > 1000  # drawn again from the kept records
    _demos_from_another_machine(kept, args, capsys)


def _demos_from_another_machine(kept, args, capsys):
    """A folder whose demonstrations were collected again on another CPU (an expert episode a step longer):
    refused, then pooled with --demos-across-machines, which the report's command and its text then say."""
    record = kept[1] / "stages" / "demos.json"
    demos = json.loads(record.read_text())
    demos["train"]["frames"] += 1
    record.write_text(json.dumps(demos))
    capsys.readouterr()
    assert cli.main(args) == 2
    assert "demonstrations differ" in capsys.readouterr().err
    assert cli.main([*args, "--demos-across-machines"]) == 0
    out = Path(args[-1])
    report = json.loads((out / "report.json").read_text())
    frames = report["demos"]["frames"]
    assert report["demos"]["frames_per_folder"] == [frames, frames + 1, frames]
    assert report["pooled_flags"][0] == "--demos-across-machines"
    from gazereg.report import results_block

    assert "--demos-across-machines" in results_block(report, "x.png").split("\n")[0]
    assert (
        f"on different machines: {frames}, {frames + 1}, {frames} frames)" in (out / "report.md").read_text()
    )


def test_folders_with_other_demonstrations_or_another_glc_are_not_one_experiment(tmp_path):
    from matplotlib.image import imsave

    from gazereg.experiment.pool import merge_outputs
    from gazereg.report.build import StageOutputs
    from gazereg.runtime.errors import UsageError

    (tmp_path / "a" / "figures").mkdir(parents=True)
    imsave(tmp_path / "a" / "figures" / "attention.png", np.zeros((2, 2, 3)))

    def outputs(demos, glc, seconds):
        return StageOutputs([], [], {**demos, "seconds": seconds}, glc, {}, {}, {}, "figures/attention.png",
                            "2026-11-25 00:00 UTC", {"train": seconds})  # fmt: skip

    demos, glc = {"episodes": 100, "frames": 8000}, {"checkpoint": "g", "eval": {"glc_f1": 0.9}, "seconds": 5}
    a, b = tmp_path / "a", tmp_path / "b"
    merged = merge_outputs([a, b], [outputs(demos, glc, 1.0), outputs(demos, None, 2.0)], tmp_path / "out")
    assert merged.glc == glc and merged.stage_times == {
        "train": 3.0
    }  # durations may differ; a folder may lack GLC
    moved = {**glc, "checkpoint": "b/glc/final", "seconds": 0.0}  # each folder's GLC lives in the folder
    assert merge_outputs([a, b], [outputs(demos, glc, 1.0), outputs(demos, moved, 1.0)], tmp_path).glc == glc
    with pytest.raises(UsageError, match="b's demonstrations differ.*--demos-across-machines"):
        merge_outputs(
            [a, b], [outputs(demos, glc, 1.0), outputs({**demos, "frames": 7999}, glc, 1.0)], tmp_path
        )
    # collected on another CPU: an expert episode a step shorter; pooled only when asked, and said
    other_cpu = [outputs(demos, glc, 1.0), outputs({**demos, "frames": 7999}, glc, 1.0)]
    across = merge_outputs([a, b], other_cpu, tmp_path, across_machines=True).demos
    assert across["frames_per_folder"] == [8000, 7999] and across["frames"] == 8000
    same = merge_outputs([a, b], [outputs(demos, glc, 1.0)] * 2, tmp_path, across_machines=True).demos
    assert "frames_per_folder" not in same
    # a record written before `without` existed is the same as one that lists no task without demonstrations
    newer = [outputs(demos, glc, 1.0), outputs({**demos, "without": []}, glc, 1.0)]
    assert "frames_per_folder" not in merge_outputs([a, b], newer, tmp_path).demos
    with pytest.raises(UsageError, match="b's demonstrations differ"):
        merge_outputs([a, b], [newer[0], outputs({**demos, "without": ["t"]}, glc, 1.0)], tmp_path, True)
    for changed in ({"episodes": 99}, {"frames": 7999, "per_task": {"t": 1}}):  # more than frames: refused
        with pytest.raises(UsageError, match="b's demonstrations differ"):
            merge_outputs(
                [a, b], [outputs(demos, glc, 1.0), outputs({**demos, **changed}, glc, 1.0)], tmp_path, True
            )
    other = {**glc, "eval": {"glc_f1": 0.8}}
    with pytest.raises(UsageError, match="b's GLC differs"):
        merge_outputs([a, b], [outputs(demos, glc, 1.0), outputs(demos, other, 1.0)], tmp_path)


def test_a_copied_priors_record_names_the_glc_checkpoints_in_its_own_folder(tmp_path):
    from gazereg.experiment.reuse import _moved

    src, out = tmp_path / "s0", tmp_path / "s1"
    record = {
        "glc": {"checkpoint": str(src / "glc" / "final"), "eval": {"glc_f1": 0.9}, "seconds": 5.0},
        "folds": [{"checkpoint": str(src / "glc" / "fold0" / "final")}, {"checkpoint": "/elsewhere/glc"}],
        "seconds": 986.0,
    }
    assert _moved(record, src, out) == {
        "glc": {"checkpoint": str(out / "glc" / "final"), "eval": {"glc_f1": 0.9}, "seconds": 0.0},
        "folds": [{"checkpoint": str(out / "glc" / "fold0" / "final")}, {"checkpoint": "/elsewhere/glc"}],
        "seconds": 0.0,
    }


@pytest.mark.parametrize(
    "flags",
    [
        ("--eval.conditions", "clean", "dim:0.5", "gaussian_noise:0.1"),  # a tuple of several values
        (
            "--train.policy.chunk",
            "8",
            "--train.policy.n-action-steps",
            "4",
            "--train.policy.image-hw",
            "96",
            "96",
            "--eval.robustness-episodes",
            "None",
        ),
    ],
)
def test_the_pooled_flags_rebuild_the_configuration_they_were_read_from(flags):
    from gazereg.experiment.pool import preset_flags
    from gazereg.runtime.config import config_diff, to_dict
    from gazereg.training.config import EXECUTION_KEYS

    cfg = built_config(("gazereg", "experiment", "--preset", "aloha", *flags))
    pooled = preset_flags(cfg, "aloha")
    assert pooled != []
    rebuilt = built_config(("gazereg", "experiment", "--preset", "aloha", *pooled))
    assert config_diff(to_dict(cfg), to_dict(rebuilt), ignore=EXECUTION_KEYS) == {}
