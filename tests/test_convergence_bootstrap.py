"""The convergence analysis's paired bootstrap (issue 36 item 4): steps to the baseline's final success and to
the threshold with percentile intervals over resampled evaluation units (training seed, task, setup seed),
one resample for every arm and checkpoint; refused when a checkpoint lacks a unit; rendered one row per arm."""

import numpy as np
import pytest

from gazereg.evaluation.stats import bootstrap_steps_to_reach, first_crossings, resample_counts
from gazereg.report.build import ReportSpec, StageOutputs, build_report
from gazereg.report.convergence import ConvergencePoint, checkpoint_outcomes, convergence_report
from gazereg.report.ids import RunId
from gazereg.report.markdown import convergence_lines

STEPS = (100, 200, 300)
UNITS = [(seed, task, setup) for seed in (0, 1) for task in ("reach-v3", "push-v3") for setup in range(5)]


def points(arm, curve):
    """ConvergencePoints of `arm`: curve[i][j] the success at STEPS[i] on UNITS[j]."""
    return [
        ConvergencePoint(RunId(arm, seed, step), task, 1000 + setup, bool(s))
        for step, row in zip(STEPS, curve)
        for (seed, task, setup), s in zip(UNITS, row)
    ]


HALF = [j % 2 == 0 for j in range(len(UNITS))]  # 10 of the 20 units
NONE, ALL = [False] * len(UNITS), [True] * len(UNITS)


def boot(curves, threshold=0.5, resamples=400, seed=0):
    pts = [p for arm, curve in curves.items() for p in points(arm, curve)]
    return convergence_report(pts, threshold, resamples=resamples, seed=seed)


def test_an_arm_like_the_baseline_reaches_its_final_at_the_last_step_and_a_perfect_one_at_the_first():
    conv = boot({"baseline": [NONE, NONE, HALF], "twin": [NONE, NONE, HALF], "perfect": [ALL, ALL, ALL]})
    final = conv["bootstrap"]["to_baseline_final"]
    for arm in ("baseline", "twin"):
        assert (
            final[arm]["steps"] == 300 and final[arm]["ci95"] == [300, 300] and final[arm]["reached"] == 1.0
        )
    assert final["twin"]["minus_reference"] == {"steps": 0, "ci95": [0, 0], "both_reached": 1.0}
    assert "minus_reference" not in final["baseline"]
    perfect = final["perfect"]
    assert perfect["steps"] == 100 and perfect["ci95"] == [100, 100] and perfect["reached"] == 1.0
    assert perfect["minus_reference"]["steps"] == -200 and perfect["minus_reference"]["ci95"] == [-200, -200]
    assert conv["bootstrap"]["to_threshold"]["perfect"]["ci95"] == [100, 100]
    assert conv["bootstrap"]["units"] == len(UNITS) and conv["bootstrap"]["resamples"] == 400


def test_a_borderline_crossing_has_not_reached_as_its_upper_end():
    """10 of 20 at the last step meets 0.5 in the sample, and in about half the resamples only."""
    conv = boot({"baseline": [NONE, NONE, HALF]})
    t = conv["bootstrap"]["to_threshold"]["baseline"]
    assert t["steps"] == 300 and t["ci95"] == [300, None] and 0.3 < t["reached"] < 0.7
    never = boot({"baseline": [NONE, NONE, NONE]})
    t = never["bootstrap"]["to_threshold"]["baseline"]
    assert t == {"steps": None, "ci95": [None, None], "reached": 0.0}


def random_curves(seed):
    rng = np.random.default_rng(seed)
    ability = rng.uniform(0, 1, size=len(UNITS))  # some setups are easier: the arms' outcomes correlate

    def curve(skill):
        return [list(rng.uniform(0, 1, len(UNITS)) < np.clip(ability + skill * k, 0, 1)) for k in (0, 1, 2)]

    return {"baseline": curve(0.15), "gaze": curve(0.3), "slow": curve(0.05)}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_sample_row_is_the_point_estimate_and_the_interval_holds_it(seed):
    conv = boot(random_curves(seed), threshold=0.6)
    inf = float("inf")
    for key, point_key in (
        ("to_baseline_final", "steps_to_baseline_final"),
        ("to_threshold", "steps_to_threshold"),
    ):
        for arm, c in (conv["bootstrap"][key] or {}).items():
            assert c["steps"] == conv["arms"][arm][point_key]  # the point estimate is today's first crossing
            lo, hi = (inf if x is None else x for x in c["ci95"])
            point = inf if c["steps"] is None else c["steps"]
            assert lo <= point <= hi, (key, arm, c)


def test_the_same_seed_gives_the_same_report_and_resamples():
    curves = random_curves(3)
    assert boot(curves, seed=7) == boot(curves, seed=7)
    assert (resample_counts(20, 50, 7) == resample_counts(20, 50, 7)).all()
    assert not (resample_counts(20, 50, 7) == resample_counts(20, 50, 8)).all()


def test_resample_counts_draw_every_unit_count_once_per_row_and_row_zero_is_the_sample():
    counts = resample_counts(6, 30, 0)
    assert counts.shape == (31, 6) and (counts[0] == 1).all() and (counts.sum(axis=1) == 6).all()
    reached = np.array([[False, True, True], [False, False, False], [True, False, True]])
    assert list(first_crossings([10, 20, 30], reached)) == [20, float("inf"), 10]


def test_a_baseline_final_of_zero_has_no_steps_to_it():
    conv = boot({"baseline": [NONE, NONE, NONE], "gaze": [NONE, HALF, ALL]})
    assert conv["baseline_final"] == 0 and conv["arms"]["gaze"]["steps_to_baseline_final"] is None
    assert conv["bootstrap"]["to_baseline_final"] is None
    assert conv["bootstrap"]["to_threshold"]["gaze"]["steps"] == 200
    lines = convergence_lines({"convergence": conv})
    assert "| arm | steps to 0.50 | reached |" in lines and not any("minus baseline's |" in x for x in lines)


def test_a_checkpoint_without_a_unit_another_evaluated_is_refused_naming_it():
    pts = points("baseline", [HALF, HALF, HALF]) + points("gaze", [HALF, HALF, HALF])
    pts = [
        p for p in pts if not (p.run.arm == "gaze" and p.run.step == 200 and p.unit == (1, "push-v3", 1003))
    ]
    message = "gaze at step 200 has no episode for \\(training seed 1, task push-v3, setup seed 1003\\)"
    with pytest.raises(ValueError, match=message):
        convergence_report(pts, 0.5)
    with pytest.raises(
        ValueError, match="evaluated \\(training seed 0, task reach-v3, setup seed 1000\\) twice"
    ):
        checkpoint_outcomes(pts + pts[:1])


def test_an_arm_may_have_fewer_checkpoints_on_the_same_units():
    pts = points("baseline", [NONE, HALF, ALL]) + points("gaze", [ALL, ALL, ALL])[-len(UNITS) :]
    units, outcomes = checkpoint_outcomes(pts)
    assert len(units) == len(UNITS) and outcomes["gaze"][0] == [300] and outcomes["gaze"][1].shape == (1, 20)
    assert outcomes["baseline"][0] == [100, 200, 300] and outcomes["baseline"][1].sum() == 30


def test_unequal_unit_counts_are_refused_by_the_bootstrap():
    with pytest.raises(ValueError, match="one unit count for every arm"):
        bootstrap_steps_to_reach(
            {"a": [1], "b": [1]}, {"a": np.ones((1, 3), bool), "b": np.ones((1, 4), bool)}, 0.5
        )
    with pytest.raises(ValueError, match="reference arm 'baseline' has no outcomes"):
        bootstrap_steps_to_reach({"a": [1]}, {"a": np.ones((1, 3), bool)}, 0.5, reference="baseline")


def test_the_rendered_rows_give_steps_intervals_reached_share_and_difference():
    conv = boot({"baseline": [NONE, NONE, HALF], "perfect": [ALL, ALL, ALL]})
    lines = convergence_lines({"convergence": conv})
    assert "| arm | 100 | 200 | 300 | steps to 0.50 | steps to baseline's final |" in lines  # kept as it was
    head = "| arm | steps to baseline's final (0.50) | reached | minus baseline's | steps to 0.50 | reached |"
    table = lines[lines.index(head) :]
    assert table[2] == "| baseline | 300 [300, 300] | 1.00 | - | 300 [300, not reached] | " + (
        f"{conv['bootstrap']['to_threshold']['baseline']['reached']:.2f} |"
    )
    assert table[3] == "| perfect | 100 [100, 100] | 1.00 | -200 [-200, -200] | 100 [100, 100] | 1.00 |"
    assert lines[lines.index(head) - 2].startswith(
        "Steps to reach a success rate, with a paired bootstrap: the 20"
    )
    del conv["bootstrap"]  # a report.json made before the bootstrap: the table it had, nothing more
    assert not any("paired bootstrap" in x for x in convergence_lines({"convergence": conv}))


def stage_outputs(checkpoint_episodes, final):
    return StageOutputs(
        episodes=final,
        checkpoint_episodes=checkpoint_episodes,
        demos={"episodes": 3, "frames": 30},
        glc=None,
        final_metrics={},
        metrics_files={},
        alignment={},
        attention_figure="figures/attention.png",
        date="today",
        stage_times={},
    )


def episodes(run, successes, start=1000):
    return [
        {"arm": str(run), "task": "reach-v3", "condition": "clean", "seed": start + i, "success": bool(s)}
        for i, s in enumerate(successes)
    ]


def test_the_report_pairs_checkpoints_with_the_final_evaluation_by_setup(tmp_path):
    """build_report carries each episode's unit from the records: the final evaluation's first
    `convergence_episodes` setups join the intermediate checkpoints' on the same units."""
    spec = ReportSpec(
        preset="unit",
        tasks=("reach-v3",),
        arms=("baseline", "gaze"),
        train_seeds=(0,),
        train_steps=10,
        batch_size=4,
        gaze_weight=0.1,
        gaze_layers=(-1,),
        eval_episodes=4,
        eval_conditions=("clean",),
        eval_seed_start=1000,
        convergence_episodes=2,
        threshold=0.5,
        config={},
    )
    base, gaze = RunId("baseline", 0), RunId("gaze", 0)
    final = episodes(base, [0, 1, 1, 1]) + episodes(gaze, [1, 1, 0, 0])
    partial = episodes(base.at_step(5), [0, 0]) + episodes(gaze.at_step(5), [1, 1])
    conv = build_report(spec, stage_outputs(partial, final), tmp_path)["convergence"]
    assert conv["bootstrap"]["units"] == 2 and conv["baseline_final"] == 0.5
    assert conv["bootstrap"]["to_baseline_final"]["gaze"]["steps"] == 5
    shifted = episodes(base.at_step(5), [0, 0]) + episodes(gaze.at_step(5), [1, 1], start=1001)
    with pytest.raises(ValueError, match="baseline at step 5 has no episode for .*setup seed 1002"):
        build_report(spec, stage_outputs(shifted, final), tmp_path)
