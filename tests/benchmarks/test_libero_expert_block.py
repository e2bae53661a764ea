"""The four LIBERO suites' expert tables on their docs pages (docs/libero.md for Spatial, docs/<suite>.md for
the others) are what `bench_libero.py --markdown` renders from the committed JSON (their numbers come from the
measurement, not typed); the markdown mode needs no LIBERO."""

from __future__ import annotations

import json

import pytest
from docs_blocks import ROOT, markdown


@pytest.mark.parametrize("suite", ["libero_spatial", "libero_object", "libero_goal", "libero_10"])
def test_the_expert_block_is_rendered_from_the_committed_json(script, suite):
    out = markdown("bench_libero.py", ROOT / "docs" / "benchmarks" / f"{suite}_expert.json")
    assert out.returncode == 0, out.stderr
    marker = f"{suite.replace('_', '-')}-expert"
    assert script.read_block(script.find_page(ROOT, marker), marker) == out.stdout
    assert out.stdout.count(f"| {suite}/") == 10


@pytest.mark.parametrize(
    "suite, task, longer",
    [("libero_spatial", 6, "libero_spatial_task6_expert"), ("libero_goal", 3, "libero_goal_task3_expert")],
)
def test_a_weak_tasks_block_is_rendered_and_its_prose_names_the_states_the_cap_failed(
    script, suite, task, longer
):
    """One task at a longer cap: the block is the JSON rendered, and the states its page says succeed
    with the longer cap are the suite table's failures of that task that this run does not have."""
    path = ROOT / "docs" / "benchmarks" / f"{longer}.json"
    out = markdown("bench_libero.py", path)
    assert out.returncode == 0, out.stderr
    marker = f"{suite.replace('_', '-')}-task{task}-expert"
    page = script.find_page(ROOT, marker)
    assert script.read_block(page, marker) == out.stdout
    short = json.loads((ROOT / "docs" / "benchmarks" / f"{suite}_expert.json").read_text())
    [same] = [t for t in short["tasks"].values() if t["task"] == f"{suite}/{task}"]
    [long] = json.loads(path.read_text())["tasks"].values()
    assert long["task"] == same["task"] and long["n"] <= same["n"]
    slow = sorted(set(same["failed_init_states"]) - set(long["failed_init_states"]))
    assert slow and f"states {', '.join(map(str, slow))}:" in page.read_text()


def test_markdown_of_a_missing_file_is_one_line_and_exit_2(tmp_path):
    r = markdown("bench_libero.py", tmp_path / "x.json")
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "x.json" in r.stderr


def test_a_failure_shows_the_phase_the_expert_stopped_in(tmp_path):
    task = {
        "task": "libero_spatial/6",
        "instruction": "pick up the bowl",
        "successes": 1,
        "n": 3,
        "failed_init_states": [0, 2],
        "failed_phases": [{"phase": "carry", "retries": 0}, {"phase": "lift", "retries": 2}],
        "mean_length": 181.0,
        "max_length": 181,
    }
    result = {
        "machine": {"cpu_model": "cpu", "cores": 2, "load_avg_before": [0.5, 0.5, 0.5]},
        "expert": "SpatialExpert",
        "init_states": [0, 1, 2],
        "suite": "libero_spatial",
        "max_steps": 400,
        "action_noise": 0.0,
        "successes": 1,
        "n": 3,
        "tasks": {"t6": task},
    }
    path = tmp_path / "expert.json"
    path.write_text(json.dumps(result))
    out = markdown("bench_libero.py", path)
    assert out.returncode == 0, out.stderr
    assert (
        "| libero_spatial/6 | pick up the bowl | 1/3 | 181 | 181 | 0 (carry), 2 (lift, 2 retries) |"
        in out.stdout
    )
