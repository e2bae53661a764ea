"""`gazereg pool`: one seed per folder, then one report, the same as the experiment run with every seed."""

import json

import pytest

from gazereg import cli

pytestmark = pytest.mark.sim

SMALL = ["--preset", "smoke", "--arms", "baseline", "gaze", "--eval.conditions", "clean", "--parallel", "1"]


def _experiment(out, *seeds):
    assert cli.main(["experiment", *SMALL, "--train-seeds", *map(str, seeds), "--out", str(out)]) == 0


def test_pooled_seed_folders_report_what_one_run_of_every_seed_reports(tmp_path, capsys):
    for seed in (0, 1):
        _experiment(tmp_path / f"s{seed}", seed)
    _experiment(tmp_path / "both", 0, 1)
    runs = ["--runs", str(tmp_path / "s0"), str(tmp_path / "s1")]
    pooled = tmp_path / "pooled"
    assert cli.main(["pool", *SMALL, "--train-seeds", "0", "1", *runs, "--out", str(pooled)]) == 0
    a = json.loads((pooled / "report.json").read_text())
    b = json.loads((tmp_path / "both" / "report.json").read_text())
    for key in ("success", "paired", "per_seed", "distance", "verdict", "alignment", "val_loss", "demos"):
        assert a[key] == b[key], key
    assert a["train"]["seeds"] == [0, 1] and a["pooled_from"] == runs[1:]
    assert a["wall_time_s"] == pytest.approx(
        sum(json.loads((tmp_path / s / "report.json").read_text())["wall_time_s"] for s in ("s0", "s1"))
    )
    assert (pooled / a["figures"]["attention"]).stat().st_size > 1000
    assert (
        f"summed over 2 runs pooled by `gazereg pool`: {', '.join(runs[1:])}."
        in (pooled / "report.md").read_text()
    )
    from gazereg.report import results_block

    assert f"(`gazereg pool --preset smoke --runs {' '.join(runs[1:])}`)" in results_block(a, "x.png")

    capsys.readouterr()  # refused, one line each: a seed missing, seeds twice, another configuration
    assert cli.main(["pool", *SMALL, "--train-seeds", "0", "1", "2", *runs, "--out", str(pooled)]) == 2
    assert "are not --train-seeds [0, 1, 2]" in capsys.readouterr().err
    twice = ["--runs", str(tmp_path / "s0"), str(tmp_path / "both")]
    assert cli.main(["pool", *SMALL, "--train-seeds", "0", "1", *twice, "--out", str(pooled)]) == 2
    assert "overlap" in capsys.readouterr().err
    changed = [*SMALL, "--train.steps", "13", "--train-seeds", "0", "1", *runs, "--out", str(pooled)]
    assert cli.main(["pool", *changed]) == 2
    assert "train.steps: 12 -> 13" in capsys.readouterr().err
    assert cli.main(["pool", *SMALL, "--train-seeds", "0", *runs[:2], "--out", str(tmp_path / "s0")]) == 2
    assert "one of the pooled folders" in capsys.readouterr().err
