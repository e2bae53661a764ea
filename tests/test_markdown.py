"""report.md and the results blocks as text (gazereg.report.markdown): byte-identical to the renderings stored in
tests/report_golden/ (made from a smoke run's report.json by tests/report_golden/regenerate.py), and each
section present exactly when the report has its data."""

import copy
import json
from pathlib import Path

import pytest

from gazereg.report import headline_lines, markdown, results_block
from gazereg.report.blockdata import BlockData
from gazereg.report.markdown import BLOCK_ALIGNMENT_KEYS, per_task_lines

GOLDEN = Path(__file__).parent / "report_golden"


@pytest.fixture
def report():
    return json.loads((GOLDEN / "smoke_report.json").read_text())


def test_report_md_is_byte_identical_to_the_golden_rendering(report):
    assert markdown(report) == (GOLDEN / "smoke_report.md").read_text()


def test_a_several_seed_results_block_is_byte_identical_to_the_golden_rendering(report):
    report["train"]["seeds"] = [0, 1]
    expected = (GOLDEN / "smoke_block_two_seeds.md").read_text()
    assert results_block(report, "figures/smoke-attention.png") == expected


def test_a_one_seed_block_is_the_headline_alignment_verdict_and_figure(report):
    for arm in set(report["success"]) - {"baseline", "gaze"}:  # two arms: the quick preset's block
        report["success"].pop(arm)
    block = results_block(report, "figures/f.png")
    head = "\n".join(headline_lines(report))
    assert block.startswith(head + "\n\nAttention vs gaze on held-out frames:\n")
    assert "Paired comparisons" not in block and "Per task" not in block  # only for several training seeds
    data = BlockData.of_report(report, BLOCK_ALIGNMENT_KEYS).line()  # the block's data line comes last
    assert block.endswith("\n".join([*report["verdict"], "", "![attention](figures/f.png)", data, ""]))
    assert head.startswith("Latest `smoke` run: ") and "(`gazereg experiment --preset smoke`)" in head
    assert head.splitlines()[-1].startswith("| gaze | ")


def test_a_one_seed_block_of_more_than_two_arms_has_the_per_task_table(report):
    assert len(report["success"]) > 2
    block = results_block(report, "figures/f.png")
    assert block.index("Per task (clean):") < block.index(report["verdict"][0])
    assert "| perturbed | 0/2 [0.00, 0.66] |" in block
    assert "## The glc arm's estimator" in block and "AUC 0.975 (centre prior 1.000" in block
    report["glc"] = None  # a run without a glc arm (the quick preset's) has no such section
    assert "glc arm's estimator" not in results_block(report, "figures/f.png")


def test_a_one_seed_block_of_more_than_two_tasks_has_the_per_task_table(report):
    tasks = ["reach-v3", "push-v3", "soccer-v3"]
    report["tasks"] = tasks
    for arm in report["success"].values():
        cell = arm["clean"]["per_task"]["reach-v3"]
        arm["clean"]["per_task"] = dict.fromkeys(tasks, cell)
    block = results_block(report, "figures/f.png")
    assert "Per task (clean):" in block and "Paired comparisons" not in block
    assert block.index("Per task (clean):") < block.index(report["verdict"][0])
    assert "| arm | reach-v3 | push-v3 | soccer-v3 |" in block  # no more tasks than arms: a row per arm


def test_a_task_level_analysis_makes_a_one_seed_block_the_powered_comparison(report):
    report["task_level"] = {
        "gaze vs baseline | clean": {
            "units": ["push-v3", "reach-v3", "soccer-v3"],
            "n": 3,
            "diffs": [0.5, -0.25, 0.125],
            "mean_diff": 0.125,
            "ci95": [-0.8, 1.05],
            "above": 2,
            "below": 1,
            "sign_flip_p": 0.75,
            "p_floor": 0.25,
        }
    }
    block = results_block(report, "figures/f.png")
    assert block.index("Paired comparisons") < block.index("## Task level (the task is the unit")
    assert "Per-task differences in the order push-v3, reach-v3, soccer-v3." in block
    assert (
        "| gaze vs baseline | clean | +0.50, -0.25, +0.12 | +0.12 [-0.80, +1.05] | 2 / 1 | 0.75 | 0.25 |"
        in block
    )
    assert (
        "| comparison (A vs B) | condition | A - B per task | mean [95% CI] | tasks above / below 0 |"
        in block
    )
    assert "## Seed level" not in block and "## Task level" in markdown(report)


def test_the_demo_preset_names_make_demo(report):
    report["preset"] = "demo"
    assert "(`make demo`)" in headline_lines(report)[0]
    report["preset"] = "quick"
    assert "(`gazereg experiment --preset quick`)" in headline_lines(report)[0]


def test_sections_follow_the_reports_data(report):
    bare = copy.deepcopy(report)
    for key in ("alignment", "glc", "distance", "val_loss", "videos"):
        bare.pop(key)
    bare.update(convergence=None, paired={})
    md = markdown(bare)
    for absent in (
        "Attention vs gaze",
        "The glc arm's estimator",
        "Closest approach",
        "Action loss on held-out",
        "Videos",
        "Paired comparisons",
        "## Convergence",
    ):
        assert absent not in md, absent
    for present in (
        "## Success",
        "Drop from clean",
        "## What the numbers say",
        "## Figures",
        "Stage times (s)",
    ):
        assert present in md, present
    assert "Attention vs gaze" not in results_block(bare, "f.png")


def test_per_seed_and_validation_loss_tables(report):
    report["per_seed"] = {"baseline@s0": {"clean": [1, 2]}, "gaze@s0": {"dim:0.7": [0, 2]}}
    report["val_loss"] = {"baseline@s0": 0.2, "baseline@s1": 0.1, "gaze@s0": 0.05, "gaze@s1": None}
    md = markdown(report)
    assert "| run | clean |" in md  # the columns: the first run's conditions; `-` where a run lacks one
    assert "| baseline@s0 | 1/2 |" in md and "| gaze@s0 | - |" in md
    assert "| baseline | 0.2000 | 0.1000 | 0.1500 |" in md and "| gaze | 0.0500 | - | 0.0500 |" in md
    report["train"]["seeds"] = [0, 1]
    assert "| baseline@s0 | 1/2 |" in results_block(report, "f.png")


def test_up_to_twelve_videos_are_linked(report):
    report["videos"] = [f"videos/v{i}.gif" for i in range(15)]
    line = next(x for x in markdown(report).splitlines() if x.startswith("Videos"))
    assert line.count("](videos/") == 12 and "[v11.gif](videos/v11.gif)" in line


def test_validation_loss_columns_are_training_seeds_in_numeric_order(report):
    report["val_loss"] = {"baseline@s0": 0.3, "baseline@s2": 0.2, "baseline@s10": 0.1, "gaze@s10": 0.05}
    md = markdown(report)
    assert "| arm | s0 | s2 | s10 | mean |" in md  # run names parsed as RunIds: seed 10 after seed 2
    assert (
        "| baseline | 0.3000 | 0.2000 | 0.1000 | 0.2000 |" in md
        and "| gaze | - | - | 0.0500 | 0.0500 |" in md
    )
    report["val_loss"] = {"baseline": 0.3}  # not a run name: refused, not shown under a "-" seed
    with pytest.raises(ValueError, match="is not a run name"):
        markdown(report)


def test_a_clean_only_run_has_no_drop_table(report):
    only_clean = copy.deepcopy(report)
    for arm in only_clean["success"].values():
        for cond in [c for c in arm if c != "clean"]:
            arm.pop(cond)
    assert "Drop from clean" in markdown(report)
    assert "Drop from clean" not in markdown(only_clean)


def test_convergence_needs_two_checkpoints_and_names_thresholds_never_reached(report):
    assert "| baseline | 0.00 | 0.00 | not reached | not reached |" in markdown(report)
    for c in report["convergence"]["arms"].values():
        c["steps"], c["rates"] = c["steps"][-1:], c["rates"][-1:]
    assert "## Convergence" not in markdown(report)  # one checkpoint: no curve to read


def test_the_header_states_the_gaze_term_only_where_an_arm_trains_with_it(report):
    from gazereg.experiment.config import ExperimentConfig
    from gazereg.experiment.records import report_spec

    spec = report_spec(ExperimentConfig(arms=("baseline", "gaze", "uniform")), "quick")
    assert (spec.gaze_arms, spec.gaze_queries) == (("gaze", "uniform"), "action")
    assert report_spec(ExperimentConfig(arms=("baseline",)), "quick").gaze_arms == ()

    report["train"].update(gaze_arms=[], gaze_queries="action")
    assert "; no arm has a gaze term." in markdown(report)
    assert "on layers" not in markdown(report)
    report["train"].update(gaze_arms=["gaze", "uniform"], gaze_queries="language")
    assert "; gaze weight 0.1 on layers [-2, -1], language queries (arms gaze, uniform)." in markdown(report)


def test_the_per_task_table_carries_each_tasks_instruction(report):
    from gazereg.experiment.demos import task_instructions

    metas = [{"task": "reach-v3", "instruction": "Reach the goal."}, {"task": "reach-v3"}]
    said = task_instructions(metas)
    assert said == {"reach-v3": "Reach the goal."}  # the first episode's
    libero = {"task": "pick_up_the_bowl", "env_name": "libero_spatial/4", "instruction": "pick up the bowl"}
    assert task_instructions([libero]) == {"libero_spatial/4": "pick up the bowl"}  # the evaluation's name
    report.setdefault("demos", {})["instructions"] = said
    lines = per_task_lines(report)
    assert lines[2].startswith("| task | instruction |")
    assert any(line.startswith("| reach-v3 | Reach the goal. |") for line in lines)


def test_a_one_seed_block_shows_how_far_episodes_got_where_the_simulator_stages_its_reward(report):
    """A staged reward (Gym-Aloha) gets its table in every block, one seed included; without one, nothing."""
    assert "Furthest stage" not in results_block(report, "figures/f.png")
    cell = {"mean": 1.5, "ci95": [1.0, 2.0], "n": 50}
    report["stage"] = {"table": {arm: {"clean": cell} for arm in report["success"]}, "paired": {}}
    block = results_block(report, "figures/f.png")
    assert "\n## Furthest stage reached (the task's staged reward; higher is better)\n" in block
    assert "| baseline | 1.50 [1.00, 2.00] |" in block
    assert block.index("Furthest stage") < block.index(report["verdict"][0])
