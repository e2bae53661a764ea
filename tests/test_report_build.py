"""The report assembled from stage outputs (no simulator): tables, convergence tally, run names."""

import json

import pytest

from gazereg.report.build import ReportSpec, StageOutputs, build_report, write_report
from gazereg.report.ids import RunId


def episodes(run, successes, condition="clean", start=1000):
    return [
        {"arm": str(run), "task": "reach-v3", "condition": condition, "seed": start + i, "success": bool(s)}
        for i, s in enumerate(successes)
    ]


def spec(seeds=(0,)):
    return ReportSpec(
        preset="unit",
        tasks=("reach-v3",),
        arms=("baseline", "gaze", "perturbed"),
        train_seeds=seeds,
        train_steps=10,
        batch_size=4,
        gaze_weight=0.1,
        gaze_layers=(-1,),
        eval_episodes=4,
        eval_conditions=("clean",),
        eval_seed_start=1000,
        convergence_episodes=2,
        threshold=0.5,
        config={"out": "x"},
    )


def test_build_report_tallies_checkpoints_and_keys_runs_by_name(tmp_path):
    runs = [RunId(arm, 0) for arm in ("baseline", "gaze", "perturbed")]
    final = (
        episodes(runs[0], [0, 0, 1, 0]) + episodes(runs[1], [1, 1, 0, 1]) + episodes(runs[2], [0, 1, 0, 0])
    )
    partial = episodes(runs[0].at_step(5), [0, 0]) + episodes(runs[1].at_step(5), [1, 0])
    metrics = {}
    for run in runs:
        metrics[run] = tmp_path / f"{run.arm}.jsonl"
        metrics[run].write_text(json.dumps({"step": 5, "loss/action": 0.5, "val/gaze_kl": 0.1}) + "\n")
    outputs = StageOutputs(
        episodes=final,
        checkpoint_episodes=partial,
        demos={"episodes": 3, "frames": 30},
        glc=None,
        final_metrics={run: {"val/loss_action": 0.25} for run in runs},
        metrics_files=metrics,
        alignment={run: {"gaze_kl": 1.0} for run in runs},
        attention_figure="figures/attention.png",
        date="today",
        stage_times={"demos": 1.0, "train": 2.0},
    )
    report = build_report(spec(), outputs, tmp_path)
    gaze = report["convergence"]["arms"]["gaze"]
    assert gaze["steps"] == [5, 10] and gaze["rates"] == [0.5, 1.0]  # the final point: the first 2 setups
    assert report["convergence"]["arms"]["perturbed"]["steps"] == [10]
    assert set(report["val_loss"]) == {"baseline@s0", "gaze@s0", "perturbed@s0"}
    assert set(report["alignment"]) == {"baseline", "gaze", "perturbed"}  # one seed: keyed by arm
    assert "gaze vs perturbed | clean" in report["paired"] and report["per_seed"] is None
    assert report["wall_time_s"] == 3.0 and report["eval"]["seeds"] == "1000..1003"
    assert (tmp_path / "figures" / "convergence.png").stat().st_size > 1000
    md = write_report(tmp_path, report)
    assert json.loads((tmp_path / "report.json").read_text())["train"]["arms"] == list(spec().arms)
    assert md.read_text().startswith("# gazereg experiment: preset `unit`")


@pytest.mark.parametrize("control", ["location", "uniform", "other_episode"])
def test_each_control_is_paired_with_the_gaze_arm(tmp_path, control):
    """With the location control (issue #21 item 6) or a gaze ablation (item 5: uniform, other-episode gaze)
    the report tests gaze against it on the same setups, next to every arm against the baseline."""
    import dataclasses

    runs = [RunId(arm, 0) for arm in ("baseline", "gaze", control)]
    final = (
        episodes(runs[0], [0, 0, 1, 0]) + episodes(runs[1], [1, 1, 0, 1]) + episodes(runs[2], [1, 0, 0, 0])
    )
    outputs = StageOutputs(
        episodes=final,
        checkpoint_episodes=[],
        demos={"episodes": 3, "frames": 30},
        glc=None,
        final_metrics={run: {} for run in runs},
        metrics_files={run: tmp_path / "none.jsonl" for run in runs},
        alignment={run: {"gaze_kl": 1.0} for run in runs},
        attention_figure="figures/attention.png",
        date="today",
        stage_times={},
    )
    report = build_report(dataclasses.replace(spec(), arms=("baseline", "gaze", control)), outputs, tmp_path)
    test = report["paired"][f"gaze vs {control} | clean"]
    assert test["pairs"] == 4 and test["gaze_only"] == 2 and test[f"{control}_only"] == 0
    assert f"{control} vs baseline | clean" in report["paired"]
    assert not any("perturbed" in name for name in report["paired"])
