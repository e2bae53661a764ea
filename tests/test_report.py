import json

import pytest

from gazereg.evaluation.summary import format_table, summarize
from gazereg.report import (
    convergence,
    distance_table,
    distance_value,
    markdown,
    paired_distance_tests,
    paired_tests,
    per_seed_table,
    per_task_paired_tests,
    results_block,
    success_table,
    unit_level_tests,
    verdict,
)
from gazereg.report.comparisons import paired_lines
from gazereg.report.progress import measure_lines, progress_sections


def records(arm, successes, condition="clean", task="reach-v3", start=1000):
    return [
        {
            "arm": arm,
            "task": task,
            "condition": condition,
            "seed": start + i,
            "success": bool(s),
            "length": 50,
        }
        for i, s in enumerate(successes)
    ]


def test_success_table_pools_seeds_and_reports_drops():
    recs = (
        records("baseline@s0", [1, 0, 1, 0])
        + records("baseline@s1", [1, 1, 0, 0])
        + records("baseline@s0", [0, 0, 1, 0], "dim:0.7")
    )
    t = success_table(recs)
    assert t["baseline"]["clean"]["successes"] == 4 and t["baseline"]["clean"]["n"] == 8
    assert t["baseline"]["dim:0.7"]["drop_from_clean"] == pytest.approx(0.5 - 0.25)
    lo, hi = t["baseline"]["clean"]["ci95"]
    assert lo < 0.5 < hi


def test_paired_tests_pair_by_seed_and_task():
    recs = records("baseline@s0", [0] * 10) + records("gaze@s0", [1] * 10)
    p = paired_tests(recs)["gaze vs baseline | clean"]
    assert p["pairs"] == 10 and p["gaze_only"] == 10 and p["baseline_only"] == 0
    assert p["mcnemar_p"] < 0.01
    assert p["rate_diff"] == 1.0 and 0.5 < p["rate_ci95"][0] < 1.0 and p["rate_ci95"][1] == 1.0
    v = verdict(success_table(recs))
    assert "do not overlap" in v[0] and "better" in v[0]
    v = verdict(success_table(recs), paired=paired_tests(recs))
    assert "(+1.00), paired difference 95% CI [+0." in v[0] and "gaze is better" in v[0]
    assert verdict(success_table(records("baseline@s0", [1, 0]))) == [
        "Only the baseline arm ran: no comparison."
    ]
    v = verdict(success_table(records("baseline@s0", [1, 0]) + records("gaze@s0", [0, 1])))
    assert "overlap, so this budget does not decide" in v[0]


def test_per_task_paired_tests_test_each_task_and_adjust_over_the_tasks():
    recs = []
    for task, gaze in (
        ("box-close-v3", [1] * 12),
        ("door-lock-v3", [0] * 6 + [1] * 6),
        ("reach-v3", [0] * 12),
    ):
        recs += records("baseline@s0", [0] * 6 + [1] * 6, task=task) + records("gaze@s0", gaze, task=task)
    tests = per_task_paired_tests(recs)["gaze vs baseline | clean"]
    assert list(tests) == ["box-close-v3", "door-lock-v3", "reach-v3"]
    box, lock, reach = tests.values()
    assert (box["gaze_only"], box["baseline_only"], box["pairs"]) == (6, 0, 12)
    assert (lock["gaze_only"], lock["baseline_only"], lock["mcnemar_p"]) == (0, 0, 1.0)
    assert (reach["gaze_only"], reach["baseline_only"]) == (0, 6)
    # 6 discordant pairs one way: p = 2 / 2^6; Holm multiplies the two smallest by 3 and 2, keeps them ordered
    assert box["mcnemar_p"] == pytest.approx(2 / 64) and box["holm_p"] == pytest.approx(3 * 2 / 64)
    assert reach["holm_p"] == pytest.approx(3 * 2 / 64) and lock["holm_p"] == 1.0
    # The pooled test sees the two tasks cancel.
    assert paired_tests(recs)["gaze vs baseline | clean"]["mcnemar_p"] == 1.0
    report = {"paired": paired_tests(recs), "paired_per_task": {"gaze vs baseline | clean": tests}}
    text = "\n".join(paired_lines(report))
    assert "## Paired comparisons per task" in text
    assert (
        "| gaze vs baseline | clean | box-close-v3 | 12 | 6 | 0 | +0.50 [" in text
        and "| 0.031 | 0.094 |" in text
    )


def test_seed_level_tests_take_the_seed_as_the_unit():
    recs = (
        records("baseline@s0", [0] * 20)
        + records("gaze@s0", [1] * 20)  # seed 0: +1.0
        + records("baseline@s1", [1] * 20)
        + records("gaze@s1", [1] * 15 + [0] * 5)  # seed 1: -0.25
        + records("gaze@s2", [1] * 20)  # no baseline at seed 2: no pairs there
    )
    t = unit_level_tests(recs)["gaze vs baseline | clean"]
    assert t["units"] == [0, 1] and t["diffs"] == [1.0, -0.25] and t["mean_diff"] == pytest.approx(0.375)
    assert (t["above"], t["below"]) == (1, 1) and t["ci95"][0] < 0 < t["ci95"][1]
    # Pooled over episodes the same data look decisive; the seeds do not.
    assert paired_tests(recs)["gaze vs baseline | clean"]["mcnemar_p"] < 0.05
    v = verdict(success_table(recs), paired=paired_tests(recs), levels={"seed": unit_level_tests(recs)})
    assert "gaze is better" in v[0] and "Seed level (2 seeds): mean +0.38" in v[0]
    assert "1 of 2 above 0 and 1 below" in v[0] and "includes 0: the seeds do not settle it" in v[0]
    assert unit_level_tests(records("baseline@s0", [0, 1]) + records("gaze@s0", [1, 1])) == {}

    # A continuous outcome: the closest approach (metres), per seed; records without it are left out.
    recs = [r for r in recs if not r["arm"].endswith("s2")]
    for r in recs:
        seed_shift = 0.02 if r["arm"].endswith("s0") else 0.04
        r["min_distance"] = 0.10 - (seed_shift if r["arm"].startswith("gaze") else 0.0)
    recs.append({**recs[0], "seed": 5000, "min_distance": None})
    recs[-1].pop("min_distance")
    d = unit_level_tests(recs, value=distance_value())["gaze vs baseline | clean"]
    assert d["diffs"] == pytest.approx([-0.02, -0.04]) and (d["above"], d["below"]) == (0, 2)


def test_unit_level_tests_take_the_task_as_the_unit():
    recs = []
    for task, (ref, arm) in {"a-v3": (2, 8), "b-v3": (5, 9), "c-v3": (10, 9)}.items():
        for run in ("baseline@s0", "baseline@s1"):
            recs += records(run, [1] * ref + [0] * (10 - ref), task=task)
        for run in ("gaze@s0", "gaze@s1"):
            recs += records(run, [1] * arm + [0] * (10 - arm), task=task)
    t = unit_level_tests(recs, "task")["gaze vs baseline | clean"]
    assert t["units"] == ["a-v3", "b-v3", "c-v3"] and t["diffs"] == pytest.approx([0.6, 0.4, -0.1])
    assert (t["n"], t["above"], t["below"]) == (3, 2, 1)
    assert unit_level_tests(recs, "seed")["gaze vs baseline | clean"]["diffs"] == pytest.approx([0.3, 0.3])
    levels = {"seed": unit_level_tests(recs, "seed"), "task": unit_level_tests(recs, "task")}
    v = verdict(success_table(recs), paired=paired_tests(recs), levels=levels)[0]
    assert "Seed level (2 seeds)" in v and "Task level (3 tasks): mean +0.30" in v
    assert "2 of 3 above 0 and 1 below" in v and "the tasks do not settle it" in v
    assert unit_level_tests(records("baseline@s0", [0, 1]) + records("gaze@s0", [1, 1]), "task") == {}


def test_distances_pool_seeds_and_pair_by_setup():
    recs = records("baseline@s0", [0] * 6) + records("baseline@s1", [0] * 6) + records("gaze@s0", [1] * 6)
    for r in recs:
        r["min_distance"] = 0.10 if r["arm"].startswith("baseline") else 0.02 + 0.001 * (r["seed"] - 1000)
    table = distance_table(recs)
    assert table["baseline"]["clean"]["n"] == 12 and table["baseline"]["clean"]["mean"] == pytest.approx(0.10)
    paired = paired_distance_tests(recs)["gaze vs baseline | clean"]
    assert paired["n"] == 6  # gaze has seed s0 only: pairs with baseline@s0, never baseline@s1
    assert paired["mean_diff"] == pytest.approx(-0.0775) and paired["p_value"] < 0.05
    assert distance_table(records("baseline@s0", [1])) == {}  # no distances recorded: no table


def test_distance_interval_uses_the_sample_sd():
    recs = records("gaze@s0", [0, 0, 0])
    for r, d in zip(recs, (0.1, 0.2, 0.3)):
        r["min_distance"] = d
    lo, hi = distance_table(recs)["gaze"]["clean"]["ci95"]
    assert (hi - lo) / 2 == pytest.approx(1.959964 * 0.1 / 3**0.5)


def test_verdict_cites_the_paired_test():
    recs = records("baseline@s0", [0] * 10) + records("gaze@s0", [1] * 10)
    v = verdict(success_table(recs), paired=paired_tests(recs))
    assert "paired McNemar p = 0.00195 < 0.05: gaze is better" in v[0]
    recs = records("baseline@s0", [0, 1, 0, 1]) + records("gaze@s0", [1, 0, 1, 1])
    v = verdict(success_table(recs), paired=paired_tests(recs))
    assert "no difference shown at this budget (the 95% intervals overlap)" in v[0]


def test_a_verdict_says_when_the_paired_interval_excludes_0_but_the_exact_test_does_not_decide():
    """The quick run's case: 32/50 vs 25/50 with 10 vs 3 discordant pairs (McNemar p 0.092) while the
    approximate paired interval excludes 0: not 'no difference shown', and not 'better' either."""
    base = [1] * 25 + [0] * 25
    gaze = [1] * 22 + [0] * 3 + [1] * 10 + [0] * 15
    recs = records("baseline@s0", base) + records("gaze@s0", gaze)
    test = paired_tests(recs)
    (name,) = test
    lo, hi = test[name]["rate_ci95"]
    assert lo > 0 and test[name]["mcnemar_p"] >= 0.05
    (line,) = verdict(success_table(recs), paired=test)
    assert (
        ">= 0.05: not shown at this budget, although the paired difference's approximate 95% CI excludes 0"
        in line
    )
    assert "no difference shown" not in line and "is better" not in line


def test_convergence_steps_to_threshold_and_baseline_final():
    conv = convergence(
        {"baseline": {100: (1, 10), 200: (4, 10)}, "gaze": {100: (5, 10), 200: (6, 10)}}, threshold=0.5
    )
    assert (
        conv["arms"]["gaze"]["steps_to_threshold"] == 100
        and conv["arms"]["baseline"]["steps_to_threshold"] is None
    )
    assert conv["arms"]["gaze"]["steps_to_baseline_final"] == 100


def test_eval_summary_and_table():
    recs = records("a", [1, 0]) + records("b", [1, 1])
    s = summarize(recs)
    assert s["arms"]["b"]["clean"]["pooled"]["successes"] == 2
    assert "a vs b | clean" in s["paired"]
    assert "| a |" in format_table(s)


def test_markdown_and_results_block():
    recs = records("baseline@s0", [1, 0]) + records("gaze@s0", [1, 1])
    success = success_table(recs)
    report = {
        "preset": "test",
        "date": "today",
        "machine": {"summary": "a test machine"},
        "wall_time_s": 60.0,
        "stage_times_s": {"train": 1.0},
        "tasks": ["reach-v3"],
        "demos": {"episodes": 2, "frames": 100},
        "train": {"steps": 10, "batch_size": 4, "seeds": [0], "gaze_weight": 0.1, "gaze_layers": [-1]},
        "eval": {"episodes": 2, "seeds": "1000..1001"},
        "success": success,
        "paired": paired_tests(recs),
        "verdict": verdict(success),
        "convergence": None,
        "alignment": {"gaze": {"gaze_kl": 0.1, "object_mass": 0.5}},
        "figures": {"attention": "figures/attention.png"},
    }
    md = markdown(report)
    assert "| gaze | 2/2 = 1.00" in md and "gaze vs baseline | clean" in md
    assert "Closest approach" not in md  # no distances recorded
    for r in recs:
        r["min_distance"] = 0.05
    report["distance"] = {"table": distance_table(recs), "paired": paired_distance_tests(recs)}
    assert "| baseline | 0.0500 [0.0500, 0.0500] |" in markdown(report)
    report["val_loss"] = {"baseline@s0": 0.2, "baseline@s1": 0.1, "gaze@s0": 0.05, "gaze@s1": None}
    assert "| baseline | 0.2000 | 0.1000 | 0.1500 |" in markdown(report)
    assert "| gaze | 0.0500 | - | 0.0500 |" in markdown(report)
    assert "attention" in results_block(report, "f.png")
    report["train"]["seeds"] = [0, 1]  # a multi-seed run's block carries the paired table, read from JSON
    reloaded = json.loads(json.dumps(report, sort_keys=True))
    assert "| gaze vs baseline | clean | 2 | 1 | 0 |" in results_block(reloaded, "f.png")
    report["per_seed"] = per_seed_table(recs)
    assert report["per_seed"] == {"baseline@s0": {"clean": [1, 2]}, "gaze@s0": {"clean": [2, 2]}}
    assert "| gaze@s0 | 2/2 |" in results_block(report, "f.png") and "| baseline@s0 | 1/2 |" in markdown(
        report
    )


def test_eval_worker_rejects_an_unknown_simulator():
    from gazereg.evaluation.rollout import RolloutWorker as Worker

    with pytest.raises(ValueError, match="unknown simulator 'gazebo'"):
        Worker(max_steps=10, gl_backend=None, env="gazebo")


def test_paired_comparison_names_are_written_and_read_in_one_place():
    from gazereg.report.tables import paired_name, split_paired_name

    recs = records("baseline@s0", [0, 1], "dim:0.7") + records("gaze@s0", [1, 1], "dim:0.7")
    (name,) = paired_tests(recs)
    assert name == paired_name("gaze", "baseline", "dim:0.7") == "gaze vs baseline | dim:0.7"
    assert split_paired_name(name) == ("gaze", "baseline", "dim:0.7")
    with pytest.raises(ValueError, match="not a paired comparison's name"):
        split_paired_name("gaze | clean")


def test_a_staged_reward_is_a_progress_section_of_its_own_only_where_recorded():
    """Gym-Aloha's episodes carry the highest staged reward (max_reward); the report then holds a `stage`
    section (per arm, and each arm against the baseline, paired by setup), and none for records without it."""
    recs = records("baseline@s0", [0] * 6) + records("gaze@s0", [0] * 5 + [1])
    assert "stage" not in progress_sections(recs, {})
    for r in recs:
        r["max_reward"] = 4.0 if r["success"] else (2.0 if r["arm"].startswith("gaze") else 1.0)
    stage = progress_sections(recs, {"uniform": []})["stage"]
    assert stage["table"]["baseline"]["clean"]["mean"] == pytest.approx(1.0)
    assert stage["table"]["gaze"]["clean"]["mean"] == pytest.approx((5 * 2.0 + 4.0) / 6)
    paired = stage["paired"]["gaze vs baseline | clean"]
    assert (
        paired["n"] == 6 and paired["mean_diff"] == pytest.approx(14 / 6 - 1.0) and paired["p_value"] < 0.05
    )
    lines = measure_lines({"stage": stage}, ["clean"], "stage")
    assert lines[1] == "## Furthest stage reached (the task's staged reward; higher is better)"
    assert "| gaze | 2.33 [" in "\n".join(lines) and measure_lines({}, ["clean"], "stage") == []
